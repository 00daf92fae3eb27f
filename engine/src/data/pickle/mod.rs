//! A safe reader for Python pickles (protocols 0–5) holding plain data and NumPy arrays.
//!
//! The Haggling dataset ships as pickles: Python-2 protocol-0 files (`S'...'` strings, arrays
//! rebuilt by `numpy.core.multiarray._reconstruct` with their raw bytes in a latin-1 string) and
//! Python-3 files (protocols 2–5, bytes via `_codecs.encode` or `BINBYTES`, `FRAME`, `MEMOIZE`,
//! `STACK_GLOBAL`). This module interprets the opcodes itself and **never executes anything**:
//! a pickle may only name the globals on a fixed whitelist, each emulated here —
//!
//! | global | emulated as |
//! |---|---|
//! | `numpy.core.multiarray._reconstruct`, `numpy._core.multiarray._reconstruct` | an empty array, filled by `BUILD` |
//! | `numpy.ndarray` | the class argument of `_reconstruct` |
//! | `numpy.dtype` | a dtype (`'f8', 0, 1`); `BUILD` state `(3, '<', ...)` sets the byte order; `'O8'` only as the dtype of a 0-d object array, which becomes its one element (`np.save` of a dict) |
//! | `numpy.core.numeric._frombuffer`, `numpy._core.numeric._frombuffer` | an array from `(buffer, dtype, shape, order)` (protocol 5) |
//! | `numpy.core.multiarray.scalar`, `numpy._core.multiarray.scalar` | a NumPy scalar → [`Value::Int`], [`Value::Float`] or [`Value::Bool`] |
//! | `_codecs.encode` | `str` → bytes (latin-1, utf-8 or ascii) |
//! | `__builtin__`/`builtins` `.set`, `.frozenset`, `.bytes`, `.bytearray` | the corresponding value |
//!
//! Any other global is an error naming it (`unknown global module.name`).
//!
//! Python-2 strings (`STRING`, `BINSTRING`, `SHORT_BINSTRING`) are decoded as latin-1 into
//! [`Value::Str`], as Python 3 does with `pickle.load(f, encoding="latin1")`; array data held in
//! such a string is turned back into bytes (every character is ≤ U+00FF by construction).
//!
//! # Untrusted input
//! A pickle is treated as hostile: no input makes the reader panic, loop forever or allocate more
//! than the file justifies. Every length field is checked against the bytes that remain; an
//! array's shape × item size must equal its data length exactly (with overflow checks), so a header
//! claiming 10¹² elements is an error, not an allocation. Shared references (`GET`, `DUP`) are kept
//! as references while reading and expanded only at the end, under a memory budget of
//! 64 × the file size + 1 MiB (so "billion laughs" pickles fail cleanly) and a nesting limit of
//! [`MAX_DEPTH`] (so self-referencing structures fail cleanly). Errors are
//! [`Error::Invalid`] messages naming the byte offset and the opcode, e.g.
//! `pickle offset 120: opcode GLOBAL (0x63): unknown global os.system (...)`;
//! [`read_pickle`] adds the file name.
//!
//! Not supported (each an error saying so): object arrays other than 0-d, structured or sub-array dtypes,
//! class instances (`INST`, `OBJ`, other globals), persistent ids, the extension registry and
//! out-of-band buffers. Array elements are widened to f64 ([`NdArray`]).
//!
//! # Layout and scope
//! [`machine`] runs the opcodes, [`value`] is the value model it produces, [`numpy`] the dtypes,
//! arrays and `ndarray.__setstate__` it emulates, [`text`] Python's string codecs. The scope is
//! frozen to what the Haggling files, pickled NumPy arrays and `np.save`d dicts of arrays
//! (VideoPose3D's Human3.6M positions) need (the table above); anything
//! else is refused with an error, never added.

mod machine;
mod numpy;
mod text;
mod value;

pub use numpy::{ByteOrder, DType, NdArray};
pub use value::{Object, Value};

use crate::{Error, Result};
use std::path::Path;

/// Deepest nesting of containers accepted in a pickle's result.
pub const MAX_DEPTH: usize = 512;

/// Largest pickle file read (the Haggling files are a few MB).
pub const MAX_FILE_BYTES: u64 = 1 << 30;

/// Reads and parses a pickle file. Errors name the file; a missing file is an I/O error.
pub fn read_pickle(path: &Path) -> Result<Value> {
    // Protocol 2+ starts with PROTO (0x80); protocol 0/1 with an opcode, which is printable ASCII.
    let starts_right = |head: &[u8]| match head.first() {
        None | Some(0x80) => Ok(()),
        Some(b) if b.is_ascii_graphic() => Ok(()),
        Some(b) => Err(format!("not a pickle (first byte 0x{b:02x} is no pickle opcode)")),
    };
    let bytes = crate::files::read_bounded_checked(path, MAX_FILE_BYTES, "pickle file", &starts_right)?;
    parse_pickle(&bytes).map_err(|e| e.in_file(path))
}

/// Parses pickle bytes (see the module documentation for what is accepted).
pub fn parse_pickle(bytes: &[u8]) -> Result<Value> {
    machine::Machine::new(bytes).run().map_err(Error::Invalid)
}

#[cfg(test)]
mod tests;
