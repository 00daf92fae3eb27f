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
//! | `numpy.dtype` | a dtype (`'f8', 0, 1`); `BUILD` state `(3, '<', ...)` sets the byte order |
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
//! Not supported (each an error saying so): object arrays, structured or sub-array dtypes,
//! class instances (`INST`, `OBJ`, other globals), persistent ids, the extension registry and
//! out-of-band buffers. Array elements are widened to f64 ([`NdArray`]).

use crate::{Error, Result};
use std::collections::HashMap;
use std::path::Path;

/// Deepest nesting of containers accepted in a pickle's result.
pub const MAX_DEPTH: usize = 512;

/// A value read from a pickle.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// `None`.
    None,
    /// `True` / `False` (also protocol 0's `I01` / `I00`).
    Bool(bool),
    /// An integer that fits in 64 bits.
    Int(i64),
    /// A larger integer: little-endian two's complement bytes, as in `LONG1`.
    BigInt(Vec<u8>),
    /// A float.
    Float(f64),
    /// A text string (Python-2 strings are decoded as latin-1).
    Str(String),
    /// A bytes or bytearray object.
    Bytes(Vec<u8>),
    /// A list.
    List(Vec<Value>),
    /// A tuple.
    Tuple(Vec<Value>),
    /// A dict as (key, value) pairs in insertion order.
    Dict(Vec<(Value, Value)>),
    /// A set or frozenset, in pickle order.
    Set(Vec<Value>),
    /// A NumPy array of a numeric or boolean dtype.
    NdArray(NdArray),
    /// A whitelisted object that is not plain data (a global, a dtype, an array never built).
    Object(Object),
}

/// Objects that appear while a pickle rebuilds NumPy values; normally consumed by the reader.
#[derive(Clone, Debug, PartialEq)]
pub enum Object {
    /// A whitelisted global (function or class) that was referenced but not called.
    Global {
        /// Module, e.g. `numpy`.
        module: String,
        /// Name, e.g. `ndarray`.
        name: String,
    },
    /// A `numpy.dtype` instance.
    Dtype(DType, ByteOrder),
    /// The empty array returned by `_reconstruct`, never filled by `BUILD`.
    UnbuiltArray,
}

/// Element types of NumPy arrays the reader accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DType {
    /// `b1` (bool)
    Bool,
    /// `i1`
    I1,
    /// `i2`
    I2,
    /// `i4`
    I4,
    /// `i8`
    I8,
    /// `u1`
    U1,
    /// `u2`
    U2,
    /// `u4`
    U4,
    /// `u8`
    U8,
    /// `f2` (half precision)
    F2,
    /// `f4`
    F4,
    /// `f8`
    F8,
}

/// Byte order of a NumPy dtype (the character in its pickled state).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ByteOrder {
    /// `<`
    Little,
    /// `>`
    Big,
    /// `=`: the writer's native order, taken to be this machine's.
    Native,
    /// `|`: single-byte types.
    NotApplicable,
}

impl ByteOrder {
    fn from_char(c: &str) -> Option<Self> {
        Some(match c {
            "<" => Self::Little,
            ">" => Self::Big,
            "=" => Self::Native,
            "|" => Self::NotApplicable,
            _ => return None,
        })
    }

    fn is_big(self) -> bool {
        match self {
            Self::Big => true,
            Self::Little => false,
            Self::Native | Self::NotApplicable => cfg!(target_endian = "big"),
        }
    }
}

impl DType {
    /// Parses a NumPy type string such as `f8`, `<i4`, `|b1` or `?`, returning the type and the
    /// byte order given by a prefix, if any.
    pub fn from_descr(descr: &str) -> Option<(DType, Option<ByteOrder>)> {
        let (order, code) = match descr.get(..1).and_then(ByteOrder::from_char) {
            Some(o) => (Some(o), &descr[1..]),
            None => (None, descr),
        };
        let dtype = match code {
            "b1" | "?" | "bool" => DType::Bool,
            "i1" | "int8" | "b" => DType::I1,
            "i2" | "int16" | "h" => DType::I2,
            "i4" | "int32" | "i" => DType::I4,
            "i8" | "int64" | "q" => DType::I8,
            "u1" | "uint8" | "B" => DType::U1,
            "u2" | "uint16" | "H" => DType::U2,
            "u4" | "uint32" | "I" => DType::U4,
            "u8" | "uint64" | "Q" => DType::U8,
            "f2" | "float16" | "e" => DType::F2,
            "f4" | "float32" | "f" => DType::F4,
            "f8" | "float64" | "d" => DType::F8,
            _ => return None,
        };
        Some((dtype, order))
    }

    /// Bytes per element.
    pub fn itemsize(self) -> usize {
        match self {
            DType::Bool | DType::I1 | DType::U1 => 1,
            DType::I2 | DType::U2 | DType::F2 => 2,
            DType::I4 | DType::U4 | DType::F4 => 4,
            DType::I8 | DType::U8 | DType::F8 => 8,
        }
    }

    /// NumPy's short name (`f8`, `i4`, `b1`, ...).
    pub fn name(self) -> &'static str {
        match self {
            DType::Bool => "b1",
            DType::I1 => "i1",
            DType::I2 => "i2",
            DType::I4 => "i4",
            DType::I8 => "i8",
            DType::U1 => "u1",
            DType::U2 => "u2",
            DType::U4 => "u4",
            DType::U8 => "u8",
            DType::F2 => "f2",
            DType::F4 => "f4",
            DType::F8 => "f8",
        }
    }

    /// Whether the type is boolean or an integer.
    pub fn is_integral(self) -> bool {
        !matches!(self, DType::F2 | DType::F4 | DType::F8)
    }

    /// Decodes one element of `self.itemsize()` bytes.
    fn decode(self, b: &[u8], big: bool) -> f64 {
        let mut buf = [0u8; 8];
        let n = self.itemsize().min(b.len());
        buf[..n].copy_from_slice(&b[..n]);
        if big {
            buf[..n].reverse();
        }
        // `buf` now holds the element little-endian in its first `n` bytes.
        match self {
            DType::Bool => (buf[0] != 0) as u8 as f64,
            DType::I1 => buf[0] as i8 as f64,
            DType::U1 => buf[0] as f64,
            DType::I2 => i16::from_le_bytes([buf[0], buf[1]]) as f64,
            DType::U2 => u16::from_le_bytes([buf[0], buf[1]]) as f64,
            DType::F2 => f16_to_f64(u16::from_le_bytes([buf[0], buf[1]])),
            DType::I4 => i32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]]) as f64,
            DType::U4 => u32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]]) as f64,
            DType::F4 => f32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]]) as f64,
            DType::I8 => i64::from_le_bytes(buf) as f64,
            DType::U8 => u64::from_le_bytes(buf) as f64,
            DType::F8 => f64::from_le_bytes(buf),
        }
    }

    /// Decodes one element exactly, as a scalar value.
    fn decode_scalar(self, b: &[u8], big: bool) -> Value {
        let mut buf = [0u8; 8];
        let n = self.itemsize().min(b.len());
        buf[..n].copy_from_slice(&b[..n]);
        if big {
            buf[..n].reverse();
        }
        match self {
            DType::Bool => Value::Bool(buf[0] != 0),
            DType::I8 => Value::Int(i64::from_le_bytes(buf)),
            DType::U8 => match i64::try_from(u64::from_le_bytes(buf)) {
                Ok(v) => Value::Int(v),
                Err(_) => Value::BigInt(buf.iter().copied().chain([0]).collect()),
            },
            DType::F2 | DType::F4 | DType::F8 => Value::Float(self.decode(b, big)),
            // i1..i4 and u1..u4 are exact in f64.
            _ => Value::Int(self.decode(b, big) as i64),
        }
    }
}

/// IEEE half precision to f64.
fn f16_to_f64(h: u16) -> f64 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let frac = (h & 0x3ff) as f64;
    match exp {
        0 => sign * frac * 2f64.powi(-24),
        31 if frac == 0.0 => sign * f64::INFINITY,
        31 => f64::NAN,
        _ => sign * (1.0 + frac / 1024.0) * 2f64.powi(exp - 15),
    }
}

/// A NumPy array with its elements widened to f64, in C (row-major) order.
///
/// 64-bit integers beyond ±2⁵³ lose precision in the conversion; booleans become 0.0 / 1.0.
#[derive(Clone, Debug, PartialEq)]
pub struct NdArray {
    /// Dimensions (empty for a 0-d array).
    pub shape: Vec<usize>,
    /// Element type in the file.
    pub dtype: DType,
    /// Elements in C order; `data.len()` is the product of `shape`.
    pub data: Vec<f64>,
}

impl NdArray {
    /// Decodes `raw` (exactly `product(shape) × itemsize` bytes, C or Fortran order) into an array.
    ///
    /// Errors (never allocations) when the shape's element count overflows or does not match
    /// the data length.
    pub fn from_bytes(raw: &[u8], shape: Vec<usize>, dtype: DType, order: ByteOrder, fortran: bool) -> Result<Self> {
        Self::decode(raw, shape, dtype, order, fortran).map_err(Error::Invalid)
    }

    fn decode(raw: &[u8], shape: Vec<usize>, dtype: DType, order: ByteOrder, fortran: bool) -> Result<Self, String> {
        let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or_else(|| format!("array shape {shape:?} has too many elements"))?;
        let nbytes = count.checked_mul(dtype.itemsize()).ok_or_else(|| format!("array shape {shape:?} has too many elements"))?;
        if nbytes != raw.len() {
            return Err(format!("array of shape {shape:?} and dtype {} needs {nbytes} bytes of data, found {}", dtype.name(), raw.len()));
        }
        let big = order.is_big();
        let flat: Vec<f64> = raw.chunks_exact(dtype.itemsize()).map(|b| dtype.decode(b, big)).collect();
        let data = if fortran && shape.len() > 1 { fortran_to_c(&flat, &shape) } else { flat };
        Ok(Self { shape, dtype, data })
    }

    /// Dimensions.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// Number of dimensions.
    pub fn ndim(&self) -> usize {
        self.shape.len()
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// Whether the array has no elements.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The elements as f64, C order.
    pub fn to_f64_vec(&self) -> Vec<f64> {
        self.data.clone()
    }

    /// The elements as f32, C order.
    pub fn to_f32(&self) -> Vec<f32> {
        self.data.iter().map(|&x| x as f32).collect()
    }

    /// The array as an `ndarray` array of f64.
    pub fn to_arrayd(&self) -> Result<ndarray::ArrayD<f64>> {
        ndarray::ArrayD::from_shape_vec(ndarray::IxDyn(&self.shape), self.data.clone())
            .map_err(|e| Error::invalid(format!("array of shape {:?}: {e}", self.shape)))
    }

    /// The array as a 2-D `ndarray` array of f32; an error if it is not 2-D.
    pub fn to_array2_f32(&self) -> Result<ndarray::Array2<f32>> {
        match *self.shape.as_slice() {
            [r, c] => ndarray::Array2::from_shape_vec((r, c), self.to_f32()).map_err(|e| Error::invalid(format!("array of shape {:?}: {e}", self.shape))),
            _ => Err(Error::invalid(format!("expected a 2-D array, found shape {:?}", self.shape))),
        }
    }
}

/// Reorders elements stored in Fortran (column-major) order into C order.
fn fortran_to_c(src: &[f64], shape: &[usize]) -> Vec<f64> {
    let n = src.len();
    let nd = shape.len();
    // Fortran strides (in elements).
    let mut fstride = vec![1usize; nd];
    for k in 1..nd {
        fstride[k] = fstride[k - 1] * shape[k - 1];
    }
    let mut out = Vec::with_capacity(n);
    let mut idx = vec![0usize; nd];
    for _ in 0..n {
        let off: usize = idx.iter().zip(&fstride).map(|(i, s)| i * s).sum();
        out.push(src[off]);
        // Advance the C-order multi-index.
        for k in (0..nd).rev() {
            idx[k] += 1;
            if idx[k] < shape[k] {
                break;
            }
            idx[k] = 0;
        }
    }
    out
}

impl Value {
    /// A short Python-like type name for messages (`int`, `str`, `ndarray`, ...).
    pub fn type_name(&self) -> &'static str {
        match self {
            Value::None => "None",
            Value::Bool(_) => "bool",
            Value::Int(_) | Value::BigInt(_) => "int",
            Value::Float(_) => "float",
            Value::Str(_) => "str",
            Value::Bytes(_) => "bytes",
            Value::List(_) => "list",
            Value::Tuple(_) => "tuple",
            Value::Dict(_) => "dict",
            Value::Set(_) => "set",
            Value::NdArray(_) => "ndarray",
            Value::Object(Object::Global { .. }) => "global",
            Value::Object(Object::Dtype(..)) => "dtype",
            Value::Object(Object::UnbuiltArray) => "unbuilt ndarray",
        }
    }

    /// For a dict: the value under a `str` or `bytes` key equal to `key` (the last one set, if the
    /// pickle repeats a key). `None` for a missing key or a non-dict.
    pub fn get(&self, key: &str) -> Option<&Value> {
        match self {
            Value::Dict(pairs) => pairs
                .iter()
                .rev()
                .find(|(k, _)| match k {
                    Value::Str(s) => s == key,
                    Value::Bytes(b) => b.as_slice() == key.as_bytes(),
                    _ => false,
                })
                .map(|(_, v)| v),
            _ => None,
        }
    }

    /// The integer value of an int, a bool (0/1) or a float with an integral value.
    pub fn as_i64(&self) -> Option<i64> {
        match *self {
            Value::Int(i) => Some(i),
            Value::Bool(b) => Some(b as i64),
            Value::Float(f) if f.fract() == 0.0 && f.abs() < 9.0e15 => Some(f as i64),
            _ => None,
        }
    }

    /// The value of a float, an int or a bool as f64.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Value::Float(f) => Some(f),
            Value::Int(i) => Some(i as f64),
            Value::Bool(b) => Some(b as u8 as f64),
            _ => None,
        }
    }

    /// The value of a bool, or of an int that is 0 or 1.
    pub fn as_bool(&self) -> Option<bool> {
        match *self {
            Value::Bool(b) => Some(b),
            Value::Int(0) => Some(false),
            Value::Int(1) => Some(true),
            _ => None,
        }
    }

    /// The text of a str, or of bytes that are valid UTF-8.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::Str(s) => Some(s),
            Value::Bytes(b) => std::str::from_utf8(b).ok(),
            _ => None,
        }
    }

    /// The contents of bytes.
    pub fn as_bytes(&self) -> Option<&[u8]> {
        match self {
            Value::Bytes(b) => Some(b),
            _ => None,
        }
    }

    /// The items of a list or a tuple.
    pub fn as_list(&self) -> Option<&[Value]> {
        match self {
            Value::List(v) | Value::Tuple(v) => Some(v),
            _ => None,
        }
    }

    /// The (key, value) pairs of a dict.
    pub fn as_dict(&self) -> Option<&[(Value, Value)]> {
        match self {
            Value::Dict(v) => Some(v),
            _ => None,
        }
    }

    /// The array of an `ndarray`.
    pub fn as_array(&self) -> Option<&NdArray> {
        match self {
            Value::NdArray(a) => Some(a),
            _ => None,
        }
    }

    /// Whether the value is `None`.
    pub fn is_none(&self) -> bool {
        matches!(self, Value::None)
    }

    /// For a dict: the value under `key`, or an error naming the missing key.
    pub fn req(&self, key: &str) -> Result<&Value> {
        match self {
            Value::Dict(_) => self.get(key).ok_or_else(|| Error::invalid(format!("missing key {key:?}"))),
            other => Err(Error::invalid(format!("expected a dict with key {key:?}, found {}", other.type_name()))),
        }
    }

    fn req_as<'a, T>(&'a self, key: &str, what: &str, f: impl FnOnce(&'a Value) -> Option<T>) -> Result<T> {
        let v = self.req(key)?;
        f(v).ok_or_else(|| Error::invalid(format!("key {key:?}: expected {what}, found {}", v.type_name())))
    }

    /// `req(key)` as an integer ([`Value::as_i64`]); the error names the key.
    pub fn req_i64(&self, key: &str) -> Result<i64> {
        self.req_as(key, "an integer", Value::as_i64)
    }

    /// `req(key)` as a number ([`Value::as_f64`]); the error names the key.
    pub fn req_f64(&self, key: &str) -> Result<f64> {
        self.req_as(key, "a number", Value::as_f64)
    }

    /// `req(key)` as text ([`Value::as_str`]); the error names the key.
    pub fn req_str(&self, key: &str) -> Result<&str> {
        self.req_as(key, "a string", Value::as_str)
    }

    /// `req(key)` as a list or tuple ([`Value::as_list`]); the error names the key.
    pub fn req_list(&self, key: &str) -> Result<&[Value]> {
        self.req_as(key, "a list", Value::as_list)
    }

    /// `req(key)` as a NumPy array ([`Value::as_array`]); the error names the key.
    pub fn req_array(&self, key: &str) -> Result<&NdArray> {
        self.req_as(key, "a numpy array", Value::as_array)
    }
}

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
    Machine::new(bytes).run().map_err(Error::Invalid)
}

// ---------------------------------------------------------------------------------------------
// The machine.
//
// Containers and memoized values live in an arena (`slots`); the stack and containers hold
// `Item`s, which are either inline scalars or references to slots. Mutating opcodes (APPEND,
// SETITEM, BUILD, ...) mutate the slot, so every reference sees the change, as in Python. Nothing
// is nested while reading, so no recursion or deep drop can happen; the result is expanded into a
// tree of `Value`s once, at STOP, under a depth limit and a memory budget.

type Res<T> = std::result::Result<T, String>;

#[derive(Clone, Debug)]
enum Item {
    /// A scalar (None, bool, int, float, str, bytes) held inline.
    Scalar(Value),
    /// A reference to a slot.
    Ref(usize),
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Global {
    Reconstruct,
    NdarrayClass,
    DtypeClass,
    Scalar,
    FromBuffer,
    Encode,
    Set,
    FrozenSet,
    Bytes,
    ByteArray,
}

#[derive(Debug)]
enum Node {
    Leaf(Value),
    List(Vec<Item>),
    Tuple(Vec<Item>),
    Dict(Vec<(Item, Item)>),
    Set(Vec<Item>),
    Global(Global, String, String),
    Dtype(DType, ByteOrder),
    ArrayStub,
}

fn global_kind(module: &str, name: &str) -> Option<Global> {
    Some(match (module, name) {
        ("numpy.core.multiarray" | "numpy._core.multiarray", "_reconstruct") => Global::Reconstruct,
        ("numpy.core.multiarray" | "numpy._core.multiarray", "scalar") => Global::Scalar,
        ("numpy.core.numeric" | "numpy._core.numeric", "_frombuffer") => Global::FromBuffer,
        ("numpy", "ndarray") => Global::NdarrayClass,
        ("numpy", "dtype") => Global::DtypeClass,
        ("_codecs", "encode") => Global::Encode,
        ("__builtin__" | "builtins", "set") => Global::Set,
        ("__builtin__" | "builtins", "frozenset") => Global::FrozenSet,
        ("__builtin__" | "builtins", "bytes") => Global::Bytes,
        ("__builtin__" | "builtins", "bytearray") => Global::ByteArray,
        _ => return None,
    })
}

fn opcode_name(op: u8) -> &'static str {
    match op {
        b'(' => "MARK",
        b'.' => "STOP",
        b'0' => "POP",
        b'1' => "POP_MARK",
        b'2' => "DUP",
        b'F' => "FLOAT",
        b'I' => "INT",
        b'J' => "BININT",
        b'K' => "BININT1",
        b'L' => "LONG",
        b'M' => "BININT2",
        b'N' => "NONE",
        b'P' => "PERSID",
        b'Q' => "BINPERSID",
        b'R' => "REDUCE",
        b'S' => "STRING",
        b'T' => "BINSTRING",
        b'U' => "SHORT_BINSTRING",
        b'V' => "UNICODE",
        b'X' => "BINUNICODE",
        b'a' => "APPEND",
        b'b' => "BUILD",
        b'c' => "GLOBAL",
        b'd' => "DICT",
        b'}' => "EMPTY_DICT",
        b'e' => "APPENDS",
        b'g' => "GET",
        b'h' => "BINGET",
        b'i' => "INST",
        b'j' => "LONG_BINGET",
        b'l' => "LIST",
        b']' => "EMPTY_LIST",
        b'o' => "OBJ",
        b'p' => "PUT",
        b'q' => "BINPUT",
        b'r' => "LONG_BINPUT",
        b's' => "SETITEM",
        b't' => "TUPLE",
        b')' => "EMPTY_TUPLE",
        b'u' => "SETITEMS",
        b'G' => "BINFLOAT",
        0x80 => "PROTO",
        0x81 => "NEWOBJ",
        0x82 => "EXT1",
        0x83 => "EXT2",
        0x84 => "EXT4",
        0x85 => "TUPLE1",
        0x86 => "TUPLE2",
        0x87 => "TUPLE3",
        0x88 => "NEWTRUE",
        0x89 => "NEWFALSE",
        0x8a => "LONG1",
        0x8b => "LONG4",
        b'B' => "BINBYTES",
        b'C' => "SHORT_BINBYTES",
        0x8c => "SHORT_BINUNICODE",
        0x8d => "BINUNICODE8",
        0x8e => "BINBYTES8",
        0x8f => "EMPTY_SET",
        0x90 => "ADDITEMS",
        0x91 => "FROZENSET",
        0x92 => "NEWOBJ_EX",
        0x93 => "STACK_GLOBAL",
        0x94 => "MEMOIZE",
        0x95 => "FRAME",
        0x96 => "BYTEARRAY8",
        0x97 => "NEXT_BUFFER",
        0x98 => "READONLY_BUFFER",
        _ => "unknown opcode",
    }
}

/// Memory accounting for expanding references into owned values.
struct Budget {
    left: usize,
    limit: usize,
}

impl Budget {
    fn charge(&mut self, bytes: usize) -> Res<()> {
        match self.left.checked_sub(bytes) {
            Some(l) => {
                self.left = l;
                Ok(())
            }
            None => Err(format!("the pickle expands to more than {} bytes in memory (shared references repeated too often)", self.limit)),
        }
    }
}

const NODE_COST: usize = std::mem::size_of::<Value>();

struct Machine<'a> {
    data: &'a [u8],
    pos: usize,
    stack: Vec<Item>,
    marks: Vec<usize>,
    memo: HashMap<u64, usize>,
    slots: Vec<Node>,
    budget: Budget,
}

impl<'a> Machine<'a> {
    fn new(data: &'a [u8]) -> Self {
        // Generous for real files (which expand a few times at most), small enough that a
        // hostile file cannot exhaust memory.
        let limit = data.len().saturating_mul(64).saturating_add(1 << 20);
        Self { data, pos: 0, stack: Vec::new(), marks: Vec::new(), memo: HashMap::new(), slots: Vec::new(), budget: Budget { left: limit, limit } }
    }

    fn run(mut self) -> Res<Value> {
        loop {
            let at = self.pos;
            let Some(&op) = self.data.get(at) else {
                return Err(format!("pickle ends at offset {at} without a STOP opcode (truncated file?)"));
            };
            self.pos += 1;
            match self.step(op) {
                Ok(Some(v)) => return Ok(v),
                Ok(None) => {}
                Err(msg) => return Err(format!("pickle offset {at}: opcode {} (0x{op:02x}): {msg}", opcode_name(op))),
            }
        }
    }

    // ----- input -----

    fn take(&mut self, n: usize) -> Res<&'a [u8]> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.data.len())
            .ok_or_else(|| format!("needs {n} bytes but only {} remain (truncated file or bad length)", self.data.len() - self.pos))?;
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn take_len(&mut self, n: u64) -> Res<&'a [u8]> {
        let n = usize::try_from(n).map_err(|_| format!("length {n} is too large"))?;
        self.take(n)
    }

    fn u8(&mut self) -> Res<u8> {
        Ok(self.take(1)?[0])
    }

    fn u16(&mut self) -> Res<u16> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self) -> Res<u32> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn i32(&mut self) -> Res<i32> {
        Ok(self.u32()? as i32)
    }

    fn u64(&mut self) -> Res<u64> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }

    /// A non-negative signed 32-bit length.
    fn len_i32(&mut self) -> Res<u64> {
        let n = self.i32()?;
        u64::try_from(n).map_err(|_| format!("negative length {n}"))
    }

    /// The bytes up to the next newline (consumed, not returned).
    fn line(&mut self) -> Res<&'a [u8]> {
        let rest = &self.data[self.pos..];
        let n = rest.iter().position(|&b| b == b'\n').ok_or("argument is not terminated by a newline (truncated file?)")?;
        self.pos += n + 1;
        Ok(&rest[..n])
    }

    fn line_str(&mut self) -> Res<&'a str> {
        let l = self.line()?;
        std::str::from_utf8(l).map_err(|_| "argument is not valid UTF-8 text".to_string())
    }

    // ----- stack -----

    fn base(&self) -> usize {
        self.marks.last().copied().unwrap_or(0)
    }

    fn push(&mut self, item: Item) {
        self.stack.push(item);
    }

    fn push_node(&mut self, node: Node) {
        self.slots.push(node);
        self.stack.push(Item::Ref(self.slots.len() - 1));
    }

    fn pop(&mut self) -> Res<Item> {
        if self.stack.len() <= self.base() {
            return Err("stack underflow".into());
        }
        self.stack.pop().ok_or_else(|| "stack underflow".into())
    }

    fn pop_mark(&mut self) -> Res<Vec<Item>> {
        let m = self.marks.pop().ok_or("no MARK on the stack")?;
        if m > self.stack.len() {
            return Err("stack underflow".into());
        }
        Ok(self.stack.split_off(m))
    }

    /// The slot of the top of the stack, moving an inline scalar into a new slot if needed (the
    /// top then becomes a reference to it).
    fn slotify_top(&mut self) -> Res<usize> {
        if self.stack.len() <= self.base() {
            return Err("stack underflow".into());
        }
        let top = self.stack.last_mut().ok_or("stack underflow")?;
        match top {
            Item::Ref(s) => Ok(*s),
            Item::Scalar(v) => {
                let v = std::mem::replace(v, Value::None);
                self.slots.push(Node::Leaf(v));
                let s = self.slots.len() - 1;
                *top = Item::Ref(s);
                Ok(s)
            }
        }
    }

    /// The slot referenced by the top of the stack (for mutating opcodes).
    fn top_slot(&self, what: &str) -> Res<usize> {
        if self.stack.len() <= self.base() {
            return Err("stack underflow".into());
        }
        match self.stack.last() {
            Some(Item::Ref(s)) => Ok(*s),
            Some(Item::Scalar(v)) => Err(format!("{what} on a {}", v.type_name())),
            None => Err("stack underflow".into()),
        }
    }

    fn slot_name(&self, s: usize) -> &'static str {
        match &self.slots[s] {
            Node::Leaf(v) => v.type_name(),
            Node::List(_) => "list",
            Node::Tuple(_) => "tuple",
            Node::Dict(_) => "dict",
            Node::Set(_) => "set",
            Node::Global(..) => "global",
            Node::Dtype(..) => "dtype",
            Node::ArrayStub => "ndarray",
        }
    }

    fn memo_put(&mut self, key: u64) -> Res<()> {
        let s = self.slotify_top()?;
        self.memo.insert(key, s);
        Ok(())
    }

    fn memo_get(&mut self, key: u64) -> Res<()> {
        let s = *self.memo.get(&key).ok_or_else(|| format!("memo index {key} was never stored"))?;
        self.push(Item::Ref(s));
        Ok(())
    }

    fn resolve(&mut self, item: &Item) -> Res<Value> {
        resolve(&self.slots, item, 0, &mut self.budget)
    }

    fn push_global(&mut self, module: &str, name: &str) -> Res<()> {
        let g = global_kind(module, name)
            .ok_or_else(|| format!("unknown global {module}.{name} (only plain data and numpy arrays can be read; nothing is executed)"))?;
        self.push_node(Node::Global(g, module.to_string(), name.to_string()));
        Ok(())
    }

    // ----- opcodes -----

    fn step(&mut self, op: u8) -> Res<Option<Value>> {
        match op {
            0x80 => {
                let v = self.u8()?;
                if v > 5 {
                    return Err(format!("unsupported pickle protocol {v}"));
                }
            }
            0x95 => {
                let n = self.u64()?;
                if n > (self.data.len() - self.pos) as u64 {
                    return Err(format!("frame of {n} bytes but only {} remain", self.data.len() - self.pos));
                }
            }
            b'.' => {
                let top = self.pop()?;
                return self.resolve(&top).map(Some);
            }
            b'(' => self.marks.push(self.stack.len()),
            b'0' => {
                if self.stack.len() > self.base() {
                    self.stack.pop();
                } else {
                    self.pop_mark()?;
                }
            }
            b'1' => {
                self.pop_mark()?;
            }
            b'2' => {
                let s = self.slotify_top()?;
                self.push(Item::Ref(s));
            }
            b'N' => self.push(Item::Scalar(Value::None)),
            0x88 => self.push(Item::Scalar(Value::Bool(true))),
            0x89 => self.push(Item::Scalar(Value::Bool(false))),
            b'I' => {
                let l = self.line()?;
                let v = match l {
                    b"00" => Value::Bool(false),
                    b"01" => Value::Bool(true),
                    _ => parse_decimal(l)?,
                };
                self.push(Item::Scalar(v));
            }
            b'L' => {
                let l = self.line()?;
                let l = l.strip_suffix(b"L").unwrap_or(l);
                let v = parse_decimal(l)?;
                self.push(Item::Scalar(v));
            }
            b'J' => {
                let v = self.i32()?;
                self.push(Item::Scalar(Value::Int(v as i64)));
            }
            b'K' => {
                let v = self.u8()?;
                self.push(Item::Scalar(Value::Int(v as i64)));
            }
            b'M' => {
                let v = self.u16()?;
                self.push(Item::Scalar(Value::Int(v as i64)));
            }
            0x8a => {
                let n = self.u8()?;
                let b = self.take(n as usize)?;
                self.push(Item::Scalar(int_from_le(b)));
            }
            0x8b => {
                let n = self.len_i32()?;
                let b = self.take_len(n)?;
                self.push(Item::Scalar(int_from_le(b)));
            }
            b'F' => {
                let l = self.line_str()?;
                let f: f64 = l.trim().parse().map_err(|_| format!("bad float {:?}", truncate(l.as_bytes())))?;
                self.push(Item::Scalar(Value::Float(f)));
            }
            b'G' => {
                let b = self.take(8)?;
                let mut a = [0u8; 8];
                a.copy_from_slice(b);
                self.push(Item::Scalar(Value::Float(f64::from_be_bytes(a))));
            }
            b'S' => {
                let l = self.line()?;
                let inner = match l {
                    [q, inner @ .., q2] if q == q2 && (*q == b'\'' || *q == b'"') => inner,
                    _ => return Err("the STRING argument must be quoted".into()),
                };
                let bytes = escape_decode(inner)?;
                self.push(Item::Scalar(Value::Str(latin1(&bytes))));
            }
            b'T' => {
                let n = self.len_i32()?;
                let b = self.take_len(n)?;
                self.push(Item::Scalar(Value::Str(latin1(b))));
            }
            b'U' => {
                let n = self.u8()?;
                let b = self.take(n as usize)?;
                self.push(Item::Scalar(Value::Str(latin1(b))));
            }
            b'V' => {
                let l = self.line()?;
                let s = raw_unicode_escape(l)?;
                self.push(Item::Scalar(Value::Str(s)));
            }
            b'X' | 0x8c | 0x8d => {
                let n = match op {
                    b'X' => self.u32()? as u64,
                    0x8c => self.u8()? as u64,
                    _ => self.u64()?,
                };
                let b = self.take_len(n)?;
                let s = std::str::from_utf8(b).map_err(|_| "string is not valid UTF-8")?;
                self.push(Item::Scalar(Value::Str(s.to_string())));
            }
            b'B' | b'C' | 0x8e | 0x96 => {
                let n = match op {
                    b'B' => self.u32()? as u64,
                    b'C' => self.u8()? as u64,
                    _ => self.u64()?,
                };
                let b = self.take_len(n)?;
                self.push(Item::Scalar(Value::Bytes(b.to_vec())));
            }
            b']' => self.push_node(Node::List(Vec::new())),
            b')' => self.push_node(Node::Tuple(Vec::new())),
            b'}' => self.push_node(Node::Dict(Vec::new())),
            0x8f => self.push_node(Node::Set(Vec::new())),
            b'l' => {
                let items = self.pop_mark()?;
                self.push_node(Node::List(items));
            }
            b't' => {
                let items = self.pop_mark()?;
                self.push_node(Node::Tuple(items));
            }
            0x85..=0x87 => {
                let n = (op - 0x84) as usize;
                let mut items = Vec::with_capacity(n);
                for _ in 0..n {
                    items.push(self.pop()?);
                }
                items.reverse();
                self.push_node(Node::Tuple(items));
            }
            b'd' => {
                let items = self.pop_mark()?;
                let pairs = into_pairs(items)?;
                self.push_node(Node::Dict(pairs));
            }
            0x91 => {
                let items = self.pop_mark()?;
                self.push_node(Node::Set(items));
            }
            b'a' => {
                let v = self.pop()?;
                let s = self.top_slot("APPEND")?;
                match &mut self.slots[s] {
                    Node::List(items) => items.push(v),
                    _ => return Err(format!("APPEND to a {}", self.slot_name(s))),
                }
            }
            b'e' => {
                let v = self.pop_mark()?;
                let s = self.top_slot("APPENDS")?;
                match &mut self.slots[s] {
                    Node::List(items) => items.extend(v),
                    _ => return Err(format!("APPENDS to a {}", self.slot_name(s))),
                }
            }
            0x90 => {
                let v = self.pop_mark()?;
                let s = self.top_slot("ADDITEMS")?;
                match &mut self.slots[s] {
                    Node::Set(items) => items.extend(v),
                    _ => return Err(format!("ADDITEMS to a {}", self.slot_name(s))),
                }
            }
            b's' => {
                let v = self.pop()?;
                let k = self.pop()?;
                let s = self.top_slot("SETITEM")?;
                match &mut self.slots[s] {
                    Node::Dict(pairs) => pairs.push((k, v)),
                    _ => return Err(format!("SETITEM on a {}", self.slot_name(s))),
                }
            }
            b'u' => {
                let items = self.pop_mark()?;
                let pairs = into_pairs(items)?;
                let s = self.top_slot("SETITEMS")?;
                match &mut self.slots[s] {
                    Node::Dict(p) => p.extend(pairs),
                    _ => return Err(format!("SETITEMS on a {}", self.slot_name(s))),
                }
            }
            b'p' => {
                let l = self.line_str()?;
                let k: u64 = l.trim().parse().map_err(|_| format!("bad memo index {:?}", truncate(l.as_bytes())))?;
                self.memo_put(k)?;
            }
            b'q' => {
                let k = self.u8()? as u64;
                self.memo_put(k)?;
            }
            b'r' => {
                let k = self.u32()? as u64;
                self.memo_put(k)?;
            }
            0x94 => {
                let k = self.memo.len() as u64;
                self.memo_put(k)?;
            }
            b'g' => {
                let l = self.line_str()?;
                let k: u64 = l.trim().parse().map_err(|_| format!("bad memo index {:?}", truncate(l.as_bytes())))?;
                self.memo_get(k)?;
            }
            b'h' => {
                let k = self.u8()? as u64;
                self.memo_get(k)?;
            }
            b'j' => {
                let k = self.u32()? as u64;
                self.memo_get(k)?;
            }
            b'c' => {
                let module = self.line_str()?;
                let name = self.line_str()?;
                self.push_global(module, name)?;
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                let (module, name) = (self.resolve(&module)?, self.resolve(&name)?);
                match (&module, &name) {
                    (Value::Str(m), Value::Str(n)) => self.push_global(m, n)?,
                    _ => return Err("STACK_GLOBAL needs two strings".into()),
                }
            }
            b'R' | 0x81 => {
                let args = self.pop()?;
                let callable = self.pop()?;
                let node = self.call(&callable, &args)?;
                self.push_node(node);
            }
            0x92 => {
                let kwargs = self.pop()?;
                let args = self.pop()?;
                let callable = self.pop()?;
                match self.resolve(&kwargs)? {
                    Value::Dict(d) if d.is_empty() => {}
                    _ => return Err("keyword arguments are not supported".into()),
                }
                let node = self.call(&callable, &args)?;
                self.push_node(node);
            }
            b'b' => {
                let state = self.pop()?;
                let s = self.top_slot("BUILD")?;
                match &self.slots[s] {
                    Node::ArrayStub => {
                        let state = self.resolve(&state)?;
                        let arr = build_array(&state, &mut self.budget)?;
                        self.slots[s] = Node::Leaf(Value::NdArray(arr));
                    }
                    Node::Dtype(dt, _) => {
                        let dt = *dt;
                        let state = self.resolve(&state)?;
                        let order = dtype_state_order(&state)?;
                        self.slots[s] = Node::Dtype(dt, order);
                    }
                    _ => return Err(format!("BUILD on a {} is not supported", self.slot_name(s))),
                }
            }
            b'P' | b'Q' => return Err("persistent ids are not supported".into()),
            0x82..=0x84 => return Err("the extension registry is not supported".into()),
            b'i' | b'o' => return Err("class instances are not supported".into()),
            0x97 | 0x98 => return Err("out-of-band buffers are not supported".into()),
            _ => return Err("unknown opcode (not a pickle, or a corrupt one)".into()),
        }
        Ok(None)
    }

    /// Emulates calling a whitelisted global (REDUCE, NEWOBJ).
    fn call(&mut self, callable: &Item, args: &Item) -> Res<Node> {
        let (g, module, name) = match callable {
            Item::Ref(s) => match &self.slots[*s] {
                Node::Global(g, m, n) => (*g, m.clone(), n.clone()),
                _ => return Err(format!("cannot call a {}", self.slot_name(*s))),
            },
            Item::Scalar(v) => return Err(format!("cannot call a {}", v.type_name())),
        };
        if matches!(g, Global::Set | Global::FrozenSet) {
            return self.call_set(args).ok_or_else(|| format!("unsupported arguments for {module}.{name}"));
        }
        let args = self.resolve(args)?;
        let Value::Tuple(args) = args else {
            return Err(format!("arguments of {module}.{name} are a {}, not a tuple", args.type_name()));
        };
        let bad = || format!("unsupported arguments for {module}.{name}");
        Ok(match g {
            Global::Reconstruct => match args.first() {
                Some(Value::Object(Object::Global { module: m, name: n })) if m == "numpy" && n == "ndarray" => Node::ArrayStub,
                _ => return Err(format!("{module}.{name} is only supported for numpy.ndarray")),
            },
            Global::NdarrayClass => return Err(format!("calling {module}.{name} directly is not supported")),
            Global::DtypeClass => {
                let descr = args.first().and_then(Value::as_str).ok_or_else(bad)?;
                let (dt, order) =
                    DType::from_descr(descr).ok_or_else(|| format!("numpy dtype {:?} is not supported (numeric and bool only)", truncate(descr.as_bytes())))?;
                Node::Dtype(dt, order.unwrap_or(ByteOrder::Native))
            }
            Global::Scalar => {
                let (Some(Value::Object(Object::Dtype(dt, order))), Some(data)) = (args.first(), args.get(1)) else {
                    return Err(bad());
                };
                let raw = raw_bytes(data)?;
                if raw.len() != dt.itemsize() {
                    return Err(format!("numpy scalar of dtype {} has {} bytes", dt.name(), raw.len()));
                }
                Node::Leaf(dt.decode_scalar(&raw, order.is_big()))
            }
            Global::FromBuffer => {
                let [buf, dtype, shape, order] = args.as_slice() else { return Err(bad()) };
                let Value::Object(Object::Dtype(dt, bo)) = dtype else { return Err(bad()) };
                let shape = parse_shape(shape)?;
                let fortran = match order.as_str() {
                    Some("C") => false,
                    Some("F") => true,
                    _ => return Err(bad()),
                };
                let raw = raw_bytes(buf)?;
                Node::Leaf(Value::NdArray(decode_array(&raw, shape, *dt, *bo, fortran, &mut self.budget)?))
            }
            Global::Encode => {
                let text = args.first().and_then(|v| match v {
                    Value::Str(s) => Some(s),
                    _ => None,
                });
                let text = text.ok_or_else(bad)?;
                let enc = match args.get(1) {
                    None => "utf-8".to_string(),
                    Some(v) => v.as_str().ok_or_else(bad)?.to_ascii_lowercase().replace('_', "-"),
                };
                let b = match enc.as_str() {
                    "latin1" | "latin-1" | "iso-8859-1" | "iso8859-1" | "l1" => latin1_encode(text)?,
                    "utf-8" | "utf8" => text.as_bytes().to_vec(),
                    "ascii" if text.is_ascii() => text.as_bytes().to_vec(),
                    _ => return Err(format!("_codecs.encode with encoding {enc:?} is not supported")),
                };
                Node::Leaf(Value::Bytes(b))
            }
            Global::Set | Global::FrozenSet => return Err(bad()),
            Global::Bytes | Global::ByteArray => match args.as_slice() {
                [] => Node::Leaf(Value::Bytes(Vec::new())),
                [Value::Bytes(b)] => Node::Leaf(Value::Bytes(b.clone())),
                [Value::List(v)] => {
                    let b: Option<Vec<u8>> = v.iter().map(|x| x.as_i64().and_then(|i| u8::try_from(i).ok())).collect();
                    Node::Leaf(Value::Bytes(b.ok_or_else(bad)?))
                }
                [Value::Str(s), enc] if enc.as_str().is_some_and(|e| e.eq_ignore_ascii_case("latin-1") || e.eq_ignore_ascii_case("latin1")) => {
                    Node::Leaf(Value::Bytes(latin1_encode(s)?))
                }
                _ => return Err(bad()),
            },
        })
    }
}

impl Machine<'_> {
    /// `set(iterable)` / `frozenset(iterable)`: the items are shared by reference, never expanded
    /// here (expanding would let chained calls nest values without the depth limit).
    fn call_set(&self, args: &Item) -> Option<Node> {
        let Item::Ref(a) = args else { return None };
        match &self.slots[*a] {
            Node::Tuple(t) if t.is_empty() => Some(Node::Set(Vec::new())),
            Node::Tuple(t) if t.len() == 1 => match &t[0] {
                Item::Ref(s) => match &self.slots[*s] {
                    Node::List(v) | Node::Tuple(v) | Node::Set(v) => Some(Node::Set(v.clone())),
                    _ => None,
                },
                Item::Scalar(_) => None,
            },
            _ => None,
        }
    }
}

/// Expands an item into an owned value (references followed), charging the budget.
fn resolve(slots: &[Node], item: &Item, depth: usize, budget: &mut Budget) -> Res<Value> {
    if depth > MAX_DEPTH {
        return Err(format!("containers nested deeper than {MAX_DEPTH} levels (or a self-referencing structure)"));
    }
    budget.charge(NODE_COST)?;
    let s = match item {
        Item::Scalar(v) => return clone_leaf(v, budget),
        Item::Ref(s) => *s,
    };
    let seq = |items: &[Item], budget: &mut Budget| -> Res<Vec<Value>> {
        budget.charge(items.len().saturating_mul(NODE_COST))?;
        items.iter().map(|i| resolve(slots, i, depth + 1, budget)).collect()
    };
    Ok(match &slots[s] {
        Node::Leaf(v) => clone_leaf(v, budget)?,
        Node::List(items) => Value::List(seq(items, budget)?),
        Node::Tuple(items) => Value::Tuple(seq(items, budget)?),
        Node::Set(items) => Value::Set(seq(items, budget)?),
        Node::Dict(pairs) => {
            budget.charge(pairs.len().saturating_mul(2 * NODE_COST))?;
            let mut out = Vec::new();
            for (k, v) in pairs {
                out.push((resolve(slots, k, depth + 1, budget)?, resolve(slots, v, depth + 1, budget)?));
            }
            Value::Dict(out)
        }
        Node::Global(_, m, n) => Value::Object(Object::Global { module: m.clone(), name: n.clone() }),
        Node::Dtype(d, o) => Value::Object(Object::Dtype(*d, *o)),
        Node::ArrayStub => Value::Object(Object::UnbuiltArray),
    })
}

/// Clones a leaf value (scalars and arrays never contain references), charging its payload.
fn clone_leaf(v: &Value, budget: &mut Budget) -> Res<Value> {
    let payload = match v {
        Value::Str(s) => s.len(),
        Value::Bytes(b) | Value::BigInt(b) => b.len(),
        Value::NdArray(a) => a.data.len().saturating_mul(8),
        _ => 0,
    };
    budget.charge(payload)?;
    Ok(v.clone())
}

fn into_pairs(items: Vec<Item>) -> Res<Vec<(Item, Item)>> {
    if items.len() % 2 == 1 {
        return Err(format!("odd number of items ({}) for key/value pairs", items.len()));
    }
    let mut it = items.into_iter();
    let mut out = Vec::new();
    while let (Some(k), Some(v)) = (it.next(), it.next()) {
        out.push((k, v));
    }
    Ok(out)
}

fn truncate(b: &[u8]) -> String {
    let s = String::from_utf8_lossy(&b[..b.len().min(40)]).into_owned();
    if b.len() > 40 {
        s + "..."
    } else {
        s
    }
}

/// Parses a protocol-0 decimal integer (Python's `int()`: surrounding whitespace allowed).
fn parse_decimal(l: &[u8]) -> Res<Value> {
    let text = std::str::from_utf8(l).map_err(|_| format!("bad integer {:?}", truncate(l)))?.trim();
    if let Ok(v) = text.parse::<i64>() {
        return Ok(Value::Int(v));
    }
    let (neg, digits) = match text.as_bytes() {
        [b'-', d @ ..] => (true, d),
        [b'+', d @ ..] => (false, d),
        d => (false, d),
    };
    if digits.is_empty() || !digits.iter().all(u8::is_ascii_digit) {
        return Err(format!("bad integer {:?}", truncate(l)));
    }
    if digits.len() > 4300 {
        return Err(format!("integer with {} digits is too long", digits.len()));
    }
    // Magnitude, little-endian base 256.
    let mut mag: Vec<u8> = vec![0];
    for &d in digits {
        let mut carry = (d - b'0') as u32;
        for b in mag.iter_mut() {
            let x = *b as u32 * 10 + carry;
            *b = x as u8;
            carry = x >> 8;
        }
        if carry > 0 {
            mag.push(carry as u8);
        }
    }
    mag.push(0); // room for the sign bit
    if neg {
        let mut carry = 1u16;
        for b in mag.iter_mut() {
            let x = (!*b) as u16 + carry;
            *b = x as u8;
            carry = x >> 8;
        }
    }
    Ok(int_from_le(&mag))
}

/// Little-endian two's complement bytes to an int (`BigInt` when it needs more than 64 bits).
fn int_from_le(b: &[u8]) -> Value {
    if b.is_empty() {
        return Value::Int(0);
    }
    let neg = b[b.len() - 1] & 0x80 != 0;
    let fill = if neg { 0xff } else { 0 };
    // Drop redundant sign-extension bytes.
    let mut n = b.len();
    while n > 1 && b[n - 1] == fill && (b[n - 2] & 0x80 != 0) == neg {
        n -= 1;
    }
    if n <= 8 {
        let mut a = [fill; 8];
        a[..n].copy_from_slice(&b[..n]);
        Value::Int(i64::from_le_bytes(a))
    } else {
        Value::BigInt(b[..n].to_vec())
    }
}

fn latin1(b: &[u8]) -> String {
    b.iter().map(|&c| c as char).collect()
}

fn latin1_encode(s: &str) -> Res<Vec<u8>> {
    s.chars().map(|c| u8::try_from(c as u32).map_err(|_| format!("character U+{:04X} cannot be encoded as latin-1", c as u32))).collect()
}

/// Python's `codecs.escape_decode` (the body of a protocol-0 `STRING`).
fn escape_decode(s: &[u8]) -> Res<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len());
    let mut i = 0;
    while i < s.len() {
        let c = s[i];
        i += 1;
        if c != b'\\' {
            out.push(c);
            continue;
        }
        let Some(&e) = s.get(i) else { return Err("trailing backslash in string".into()) };
        i += 1;
        match e {
            b'\n' => {}
            b'\\' => out.push(b'\\'),
            b'\'' => out.push(b'\''),
            b'"' => out.push(b'"'),
            b'b' => out.push(8),
            b'f' => out.push(12),
            b't' => out.push(b'\t'),
            b'n' => out.push(b'\n'),
            b'r' => out.push(b'\r'),
            b'v' => out.push(11),
            b'a' => out.push(7),
            b'0'..=b'7' => {
                let mut v = (e - b'0') as u32;
                for _ in 0..2 {
                    match s.get(i) {
                        Some(&d @ b'0'..=b'7') => {
                            v = v * 8 + (d - b'0') as u32;
                            i += 1;
                        }
                        _ => break,
                    }
                }
                out.push(v as u8);
            }
            b'x' => {
                let h = s.get(i..i + 2).and_then(|h| std::str::from_utf8(h).ok()).and_then(|h| u8::from_str_radix(h, 16).ok());
                match h {
                    Some(v) if s[i].is_ascii_hexdigit() && s[i + 1].is_ascii_hexdigit() => {
                        out.push(v);
                        i += 2;
                    }
                    _ => return Err(format!("invalid \\x escape at position {}", i - 2)),
                }
            }
            other => {
                out.push(b'\\');
                out.push(other);
            }
        }
    }
    Ok(out)
}

/// Python's `raw-unicode-escape` decoding (the body of a protocol-0 `UNICODE`): bytes are
/// latin-1 code points, except `\uXXXX` / `\UXXXXXXXX` after an odd number of backslashes.
fn raw_unicode_escape(s: &[u8]) -> Res<String> {
    let mut out = String::with_capacity(s.len());
    let mut i = 0;
    while i < s.len() {
        if s[i] != b'\\' {
            out.push(s[i] as char);
            i += 1;
            continue;
        }
        let start = i;
        while i < s.len() && s[i] == b'\\' {
            out.push('\\');
            i += 1;
        }
        let odd = (i - start) % 2 == 1;
        let count = match s.get(i) {
            Some(b'u') if odd => 4,
            Some(b'U') if odd => 8,
            _ => continue,
        };
        out.pop();
        i += 1;
        let hex = s
            .get(i..i + count)
            .filter(|h| h.iter().all(u8::is_ascii_hexdigit))
            .ok_or_else(|| format!("truncated \\{} escape at position {}", if count == 4 { 'u' } else { 'U' }, i - 2))?;
        let code = u32::from_str_radix(std::str::from_utf8(hex).map_err(|_| "bad escape")?, 16).map_err(|_| "bad escape")?;
        let ch = char::from_u32(code).ok_or_else(|| format!("escape \\u{code:x} is not a valid character"))?;
        out.push(ch);
        i += count;
    }
    Ok(out)
}

/// Raw array data from bytes, or from a latin-1 string (Python-2 pickles).
fn raw_bytes(v: &Value) -> Res<Vec<u8>> {
    match v {
        Value::Bytes(b) => Ok(b.clone()),
        Value::Str(s) => latin1_encode(s),
        Value::List(_) | Value::Tuple(_) => Err("object arrays (dtype 'O') are not supported".into()),
        other => Err(format!("array data is a {}, expected bytes", other.type_name())),
    }
}

fn parse_shape(v: &Value) -> Res<Vec<usize>> {
    let items = v.as_list().ok_or_else(|| format!("array shape is a {}, expected a tuple", v.type_name()))?;
    items
        .iter()
        .map(|d| match d {
            Value::Int(i) => usize::try_from(*i).map_err(|_| format!("negative array dimension {i}")),
            other => Err(format!("array dimension is a {}", other.type_name())),
        })
        .collect()
}

fn decode_array(raw: &[u8], shape: Vec<usize>, dt: DType, order: ByteOrder, fortran: bool, budget: &mut Budget) -> Res<NdArray> {
    // The element count is checked against `raw.len()` before anything is allocated; the f64
    // copy is charged to the budget like any other expansion.
    budget.charge((raw.len() / dt.itemsize()).saturating_mul(8))?;
    NdArray::decode(raw, shape, dt, order, fortran)
}

/// The byte order in a dtype's `BUILD` state `(version, order, subarray, names, fields, ...)`.
fn dtype_state_order(state: &Value) -> Res<ByteOrder> {
    let items = state.as_list().ok_or("dtype state is not a tuple")?;
    let order = match items {
        // (version, byteorder, subdescr, names, fields, elsize, alignment[, flags[, metadata]])
        [Value::Int(_), o, sub, names, fields, ..] => {
            if !sub.is_none() || !names.is_none() || !fields.is_none() {
                return Err("structured or sub-array dtypes are not supported".into());
            }
            o
        }
        _ => return Err("unrecognised dtype state".into()),
    };
    order.as_str().and_then(ByteOrder::from_char).ok_or_else(|| "dtype state has no valid byte order".into())
}

/// Fills an array from `ndarray.__setstate__` state: `(version, shape, dtype, is_fortran, data)`
/// (or the older form without `version`).
fn build_array(state: &Value, budget: &mut Budget) -> Res<NdArray> {
    let items = state.as_list().ok_or("ndarray state is not a tuple")?;
    let (shape, dtype, fortran, data) = match items {
        [Value::Int(_), s, d, f, r] | [s, d, f, r] => (s, d, f, r),
        _ => return Err(format!("ndarray state has {} items, expected 5", items.len())),
    };
    let shape = parse_shape(shape)?;
    let Value::Object(Object::Dtype(dt, order)) = dtype else {
        return Err(format!("ndarray state holds a {} where a dtype was expected", dtype.type_name()));
    };
    let fortran = fortran.as_bool().ok_or("ndarray state has no Fortran-order flag")?;
    let raw = raw_bytes(data)?;
    decode_array(&raw, shape, *dt, *order, fortran, budget)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(bytes: &[u8]) -> Value {
        match parse_pickle(bytes) {
            Ok(v) => v,
            Err(e) => panic!("parse failed: {e}"),
        }
    }

    fn err(bytes: &[u8]) -> String {
        match parse_pickle(bytes) {
            Ok(v) => panic!("expected an error, got {v:?}"),
            Err(e) => e.to_string(),
        }
    }

    fn s(x: &str) -> Value {
        Value::Str(x.into())
    }

    #[test]
    fn protocol0_scalars() {
        assert_eq!(p(b"I42\n."), Value::Int(42));
        assert_eq!(p(b"I-7\n."), Value::Int(-7));
        assert_eq!(p(b"I01\n."), Value::Bool(true));
        assert_eq!(p(b"I00\n."), Value::Bool(false));
        assert_eq!(p(b"L12345678901234L\n."), Value::Int(12345678901234));
        assert_eq!(p(b"F1.5\n."), Value::Float(1.5));
        assert!(matches!(p(b"Fnan\n."), Value::Float(f) if f.is_nan()));
        assert_eq!(p(b"F-inf\n."), Value::Float(f64::NEG_INFINITY));
        assert_eq!(p(b"N."), Value::None);
        // 2**70 and -2**70: little-endian two's complement.
        let big = {
            let mut b = vec![0u8; 9];
            b[8] = 0x40;
            b
        };
        assert_eq!(p(b"L1180591620717411303424L\n."), Value::BigInt(big));
        let nbig = {
            let mut b = vec![0u8; 9];
            b[8] = 0xc0;
            b
        };
        assert_eq!(p(b"L-1180591620717411303424L\n."), Value::BigInt(nbig));
        assert_eq!(p(b"L-9223372036854775808L\n."), Value::Int(i64::MIN));
    }

    #[test]
    fn protocol0_strings_and_escapes() {
        assert_eq!(p(b"S'abc'\n."), s("abc"));
        assert_eq!(p(b"S\"it's\"\n."), s("it's"));
        assert_eq!(p(b"S'a\\'b\\\\c\\n\\t\\x41\\101\\0\\7z'\n."), s("a'b\\c\n\tAA\0\u{7}z"));
        // Unknown escapes keep the backslash; bytes ≥ 0x80 are latin-1.
        assert_eq!(p(b"S'\\q\\xf0\\xff'\n."), s("\\q\u{f0}\u{ff}"));
        assert!(err(b"S'abc\n.").contains("quoted"));
        assert!(err(b"S'\\x4'\n.").contains("\\x escape"));
        assert!(err(b"S'ab\\'\n.").contains("trailing backslash"));
        // UNICODE: raw-unicode-escape.
        assert_eq!(p(b"Vh\\u00e9llo \\U0001F600\n."), s("h\u{e9}llo \u{1F600}"));
        assert_eq!(p(b"V\\\\u0041\n."), s("\\\\u0041"));
        assert_eq!(p(b"V\xe9\n."), s("\u{e9}"));
        assert!(err(b"V\\u12\n.").contains("truncated"));
    }

    #[test]
    fn protocol0_containers_and_memo() {
        // Python 2: pickle.dumps({'a': [1, 2], 'b': ('x', 'x')}, 0)
        let v = p(b"(dp0\nS'a'\np1\n(lp2\nI1\naI2\nasS'b'\np3\n(S'x'\np4\ng4\ntp5\ns.");
        assert_eq!(v.get("a"), Some(&Value::List(vec![Value::Int(1), Value::Int(2)])));
        assert_eq!(v.get("b"), Some(&Value::Tuple(vec![s("x"), s("x")])));
        // A memoized list mutated after PUT is seen through GET (reference semantics).
        let v = p(b"(lp0\nI1\nag0\nI2\na0g0\n.");
        assert_eq!(v, Value::List(vec![Value::Int(1), Value::Int(2)]));
        // DICT, LIST and TUPLE from MARK, POP, POP_MARK, DUP.
        let v = p(b"(S'k'\nI1\nd.");
        assert_eq!(v.req_i64("k").unwrap(), 1);
        assert_eq!(p(b"(I1\nI2\nl."), Value::List(vec![Value::Int(1), Value::Int(2)]));
        assert_eq!(p(b"I1\nI2\n0."), Value::Int(1));
        assert_eq!(p(b"I1\n(I2\nI3\n1."), Value::Int(1));
        assert_eq!(p(b"(lp0\n2I5\na0."), Value::List(vec![Value::Int(5)]));
        assert_eq!(p(b"(t."), Value::Tuple(vec![]));
    }

    #[test]
    fn binary_opcodes() {
        // Protocol 2: [True, False, None, 1, 300, 70000, -1, 1.5, 2**64, 'é', 'abc']
        let mut b = vec![0x80, 2, b']', b'q', 0, b'(', 0x88, 0x89, b'N', b'K', 1, b'M', 0x2c, 0x01];
        b.extend([b'J', 0x70, 0x11, 0x01, 0x00, b'J', 0xff, 0xff, 0xff, 0xff, b'G']);
        b.extend(1.5f64.to_be_bytes());
        b.extend([0x8a, 9, 0, 0, 0, 0, 0, 0, 0, 0, 1]);
        b.extend([b'X', 2, 0, 0, 0, 0xc3, 0xa9, b'U', 3, b'a', b'b', b'c', b'e', b'.']);
        let v = p(&b);
        let l = v.as_list().unwrap();
        assert_eq!(&l[..7], &[Value::Bool(true), Value::Bool(false), Value::None, Value::Int(1), Value::Int(300), Value::Int(70000), Value::Int(-1)]);
        assert_eq!(l[7], Value::Float(1.5));
        assert_eq!(l[8], Value::BigInt(vec![0, 0, 0, 0, 0, 0, 0, 0, 1]));
        assert_eq!(l[9], s("é"));
        assert_eq!(l[10], s("abc"));
        // LONG1 that fits, LONG4, negative LONG1.
        assert_eq!(p(&[0x8a, 2, 0xff, 0x7f, b'.']), Value::Int(32767));
        assert_eq!(p(&[0x8a, 1, 0xff, b'.']), Value::Int(-1));
        assert_eq!(p(&[0x8a, 0, b'.']), Value::Int(0));
        assert_eq!(p(&[0x8b, 2, 0, 0, 0, 0x00, 0x80, b'.']), Value::Int(-32768));
        // Bytes family (protocol 3+), bytearray (5), BINSTRING.
        assert_eq!(p(&[0x80, 3, b'C', 2, 1, 2, b'.']), Value::Bytes(vec![1, 2]));
        assert_eq!(p(&[b'B', 1, 0, 0, 0, 9, b'.']), Value::Bytes(vec![9]));
        assert_eq!(p(&[0x8e, 1, 0, 0, 0, 0, 0, 0, 0, 7, b'.']), Value::Bytes(vec![7]));
        assert_eq!(p(&[0x96, 1, 0, 0, 0, 0, 0, 0, 0, 8, b'.']), Value::Bytes(vec![8]));
        assert_eq!(p(&[b'T', 2, 0, 0, 0, b'h', 0xe9, b'.']), s("h\u{e9}"));
        assert_eq!(p(&[0x8d, 1, 0, 0, 0, 0, 0, 0, 0, b'z', b'.']), s("z"));
        // Tuples, dicts, sets.
        assert_eq!(p(&[b'K', 1, b'K', 2, b'K', 3, 0x87, b'.']), Value::Tuple(vec![Value::Int(1), Value::Int(2), Value::Int(3)]));
        assert_eq!(p(&[b'K', 1, 0x85, b'.']), Value::Tuple(vec![Value::Int(1)]));
        assert_eq!(p(b")."), Value::Tuple(vec![]));
        let d = p(&[b'}', b'(', 0x8c, 1, b'a', b'K', 1, 0x8c, 1, b'b', b'K', 2, b'u', 0x8c, 1, b'c', b'K', 3, b's', b'.']);
        assert_eq!((d.req_i64("a").unwrap(), d.req_i64("b").unwrap(), d.req_i64("c").unwrap()), (1, 2, 3));
        let st = p(&[0x8f, b'(', b'K', 1, b'K', 2, 0x90, b'.']);
        assert_eq!(st, Value::Set(vec![Value::Int(1), Value::Int(2)]));
        assert_eq!(p(&[b'(', b'K', 4, 0x91, b'.']), Value::Set(vec![Value::Int(4)]));
        // Memo: BINPUT/BINGET/LONG_BINPUT/LONG_BINGET/MEMOIZE.
        let v = p(&[b']', b'r', 5, 0, 0, 0, b'K', 1, b'a', b'j', 5, 0, 0, 0, 0x86, b'.']);
        assert_eq!(v, Value::Tuple(vec![Value::List(vec![Value::Int(1)]); 2]));
        let v = p(&[0x8c, 1, b'x', 0x94, b'h', 0, 0x86, b'.']);
        assert_eq!(v, Value::Tuple(vec![s("x"), s("x")]));
        // Bytes keys are found by `get` too.
        let d = p(&[b'}', b'C', 1, b'k', b'K', 9, b's', b'.']);
        assert_eq!(d.get("k"), Some(&Value::Int(9)));
    }

    #[test]
    fn python3_protocols_with_codecs_and_frames() {
        // pickle.dumps({'a': b'\x00\xff', 'b': {1, 2}}, protocol=2) from CPython 3.11.
        let b = b"\x80\x02}q\x00(X\x01\x00\x00\x00aq\x01c_codecs\nencode\nq\x02X\x03\x00\x00\x00\x00\xc3\xbfq\x03X\x06\x00\x00\x00latin1q\x04\x86q\x05Rq\x06X\x01\x00\x00\x00bq\x07c__builtin__\nset\nq\x08]q\t(K\x01K\x02e\x85q\nRq\x0bu.";
        let v = p(b);
        assert_eq!(v.get("a"), Some(&Value::Bytes(vec![0, 255])));
        assert_eq!(v.get("b"), Some(&Value::Set(vec![Value::Int(1), Value::Int(2)])));
        // pickle.dumps({'a': b'\x00\xff', 'b': frozenset([3])}, protocol=4).
        let b = b"\x80\x04\x95\x17\x00\x00\x00\x00\x00\x00\x00}\x94(\x8c\x01a\x94C\x02\x00\xff\x94\x8c\x01b\x94(K\x03\x91\x94u.";
        let v = p(b);
        assert_eq!(v.get("a"), Some(&Value::Bytes(vec![0, 255])));
        assert_eq!(v.get("b"), Some(&Value::Set(vec![Value::Int(3)])));
        // pickle.dumps(b'', protocol=2) uses __builtin__.bytes with no arguments.
        assert_eq!(p(b"\x80\x02c__builtin__\nbytes\nq\x00)Rq\x01."), Value::Bytes(vec![]));
        // pickle.dumps(bytearray(b'\x01'), protocol=2).
        let b = b"\x80\x02c__builtin__\nbytearray\nq\x00c_codecs\nencode\nq\x01X\x01\x00\x00\x00\x01q\x02X\x06\x00\x00\x00latin1q\x03\x86q\x04Rq\x05\x85q\x06Rq\x07.";
        assert_eq!(p(b), Value::Bytes(vec![1]));
        // The same dict as the protocol-2 one, with protocol 0 (UNICODE strings, set from a list).
        let b =
            b"(dp0\nVa\np1\nc_codecs\nencode\np2\n(V\\u0000\xff\np3\nVlatin1\np4\ntp5\nRp6\nsVb\np7\nc__builtin__\nset\np8\n((lp9\nI1\naI2\natp10\nRp11\ns.";
        let v = p(b);
        assert_eq!(v.get("a"), Some(&Value::Bytes(vec![0, 255])));
        assert_eq!(v.get("b"), Some(&Value::Set(vec![Value::Int(1), Value::Int(2)])));
        // A frame longer than the file is an error.
        assert!(err(b"\x80\x04\x95\xff\x00\x00\x00\x00\x00\x00\x00N.").contains("frame"));
        assert!(err(b"\x80\x06N.").contains("protocol 6"));
    }

    /// Protocol-0 numpy array as Python 2 + numpy 1.x writes it.
    fn np0(shape: &str, descr: &str, order: &str, fortran: &str, data: &str) -> Vec<u8> {
        format!(
            "cnumpy.core.multiarray\n_reconstruct\np1\n(cnumpy\nndarray\np2\n(I0\ntp3\nS'b'\np4\ntp5\nRp6\n(I1\n({shape}tp7\ncnumpy\ndtype\np8\n(S'{descr}'\np9\nI0\nI1\ntp10\nRp11\n(I3\nS'{order}'\np12\nNNNI-1\nI-1\nI0\ntp13\nbI{fortran}\nS'{data}'\np14\ntp15\nb."
        )
        .into_bytes()
    }

    #[test]
    fn numpy_protocol0_arrays() {
        // f8 [2] = [0.0, 1.0]
        let v = p(&np0("I2\n", "f8", "<", "00", "\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\xf0?"));
        let a = v.as_array().unwrap();
        assert_eq!((a.shape(), a.dtype, a.data.as_slice()), (&[2usize][..], DType::F8, &[0.0, 1.0][..]));
        // i2 big-endian, shape (2, 2), Fortran order: memory [1, 3, 2, 4] → C [[1, 2], [3, 4]].
        let v = p(&np0("I2\nI2\n", "i2", ">", "01", "\\x00\\x01\\x00\\x03\\x00\\x02\\x00\\x04"));
        let a = v.as_array().unwrap();
        assert_eq!((a.shape(), a.dtype, a.to_f32()), (&[2usize, 2][..], DType::I2, vec![1.0, 2.0, 3.0, 4.0]));
        // b1 / u1 / i1 with '|'.
        let v = p(&np0("I3\n", "b1", "|", "00", "\\x00\\x01\\x00"));
        assert_eq!(v.as_array().unwrap().data, vec![0.0, 1.0, 0.0]);
        let v = p(&np0("I2\n", "i1", "|", "00", "\\xff\\x7f"));
        assert_eq!(v.as_array().unwrap().data, vec![-1.0, 127.0]);
        let v = p(&np0("I1\n", "u4", "<", "00", "\\xff\\xff\\xff\\xff"));
        assert_eq!(v.as_array().unwrap().data, vec![4294967295.0]);
        let v = p(&np0("I1\n", "f2", "<", "00", "\\x00<"));
        assert_eq!(v.as_array().unwrap().data, vec![1.0]);
        let v = p(&np0("I1\n", "f4", ">", "00", "?\\x80\\x00\\x00"));
        assert_eq!(v.as_array().unwrap().data, vec![1.0]);
        // 0-d array, empty array.
        let v = p(&np0("", "i8", "<", "00", "\\x05\\x00\\x00\\x00\\x00\\x00\\x00\\x00"));
        assert_eq!((v.as_array().unwrap().shape(), v.as_array().unwrap().data.as_slice()), (&[][..], &[5.0][..]));
        let v = p(&np0("I0\nI3\n", "f8", "<", "00", ""));
        assert_eq!((v.as_array().unwrap().shape(), v.as_array().unwrap().len()), (&[0usize, 3][..], 0));
        // Lying headers: wrong length, 10^12 elements, overflowing product, negative dim.
        assert!(err(&np0("I3\n", "f8", "<", "00", "\\x00")).contains("needs 24 bytes"));
        assert!(err(&np0("I1000000\nI1000000\n", "f8", "<", "00", "\\x00")).contains("needs 8000000000000 bytes"));
        assert!(err(&np0("I4294967296\nI4294967296\nI4294967296\n", "f8", "<", "00", "")).contains("too many elements"));
        assert!(err(&np0("I-1\n", "f8", "<", "00", "")).contains("negative"));
        // Unsupported dtypes are named.
        assert!(err(&np0("I1\n", "O8", "|", "00", "")).contains("\"O8\""));
        assert!(err(&np0("I1\n", "f8", "?", "00", "")).contains("byte order"));
    }

    #[test]
    fn numpy_scalars() {
        // pickle.dumps(np.float64(1.5), protocol=2) with numpy 2.
        let b = b"\x80\x02cnumpy._core.multiarray\nscalar\nq\x00cnumpy\ndtype\nq\x01X\x02\x00\x00\x00f8q\x02\x89\x88\x87q\x03Rq\x04(K\x03X\x01\x00\x00\x00<q\x05NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tq\x06bc_codecs\nencode\nq\x07X\t\x00\x00\x00\x00\x00\x00\x00\x00\x00\xc3\xb8?q\x08X\x06\x00\x00\x00latin1q\t\x86q\nRq\x0b\x86q\x0cRq\r.";
        assert_eq!(p(b), Value::Float(1.5));
        // pickle.dumps(np.int32(-3), protocol=0).
        let b = b"cnumpy._core.multiarray\nscalar\np0\n(cnumpy\ndtype\np1\n(Vi4\np2\nI00\nI01\ntp3\nRp4\n(I3\nV<\np5\nNNNI-1\nI-1\nI0\ntp6\nbc_codecs\nencode\np7\n(V\xfd\xff\xff\xff\np8\nVlatin1\np9\ntp10\nRp11\ntp12\nRp13\n.";
        assert_eq!(p(b), Value::Int(-3));
    }

    fn fixture(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/haggling").join(name)
    }

    /// Real NumPy pickles, protocols 0–5 (`make_numpy_fixtures.py`): every dtype, both byte
    /// orders, C and Fortran order, 0-d and empty arrays, scalars, shared references; protocol 4
    /// and 5 use FRAME / MEMOIZE / STACK_GLOBAL, protocol 5 `_frombuffer` with BYTEARRAY8.
    #[test]
    fn real_numpy_pickles_all_protocols() {
        for proto in 0..=5 {
            let v = read_pickle(&fixture(&format!("numpy_p{proto}.pkl"))).unwrap_or_else(|e| panic!("protocol {proto}: {e}"));
            let arr = |k: &str| -> &NdArray { v.req_array(k).unwrap_or_else(|e| panic!("protocol {proto}: {e}")) };
            let check = |k: &str, dtype: DType, shape: &[usize], data: Vec<f64>| {
                let a = arr(k);
                assert_eq!((a.dtype, a.shape(), &a.data), (dtype, shape, &data), "protocol {proto}, key {k}");
            };
            check("f8", DType::F8, &[2, 3], (0..6).map(|i| i as f64 / 4.0).collect());
            check("f4_be", DType::F4, &[3, 2], (0..6).map(|i| i as f64 - 2.5).collect());
            check("i2_fortran", DType::I2, &[3, 4], (0..12).map(|i| i as f64 - 5.0).collect());
            check("i4_3d_fortran", DType::I4, &[2, 3, 4], (0..24).map(|i| i as f64).collect());
            check("i8_be", DType::I8, &[2], vec![-(2f64.powi(40)), 7.0]);
            check("i1", DType::I1, &[2], vec![-128.0, 127.0]);
            check("u1", DType::U1, &[6], (250..256).map(|i| i as f64).collect());
            check("u2_be", DType::U2, &[2], vec![65535.0, 1.0]);
            check("u4", DType::U4, &[1], vec![4294967295.0]);
            check("u8", DType::U8, &[1], vec![2f64.powi(63) + 2048.0]);
            check("b1", DType::Bool, &[3], vec![1.0, 0.0, 1.0]);
            check("f2", DType::F2, &[3], vec![0.5, -2.0, 65504.0]);
            check("zero_d", DType::F8, &[], vec![7.25]);
            check("empty", DType::F8, &[0, 3], vec![]);
            assert_eq!(v.get("scalar_f8"), Some(&Value::Float(2.5)), "protocol {proto}");
            assert_eq!(v.get("scalar_i8"), Some(&Value::Int(-9)), "protocol {proto}");
            assert_eq!(v.get("scalar_bool"), Some(&Value::Bool(true)), "protocol {proto}");
            let plain =
                Value::List(vec![Value::Int(1), s("two"), Value::Float(3.0), Value::None, Value::Tuple(vec![Value::Bool(true), Value::Bytes(vec![0, 1])])]);
            assert_eq!(v.get("plain"), Some(&plain), "protocol {proto}");
            let shared = v.req_list("shared").unwrap();
            assert_eq!(shared.len(), 2);
            for a in shared {
                assert_eq!(a.as_array().map(|a| a.data.clone()), Some(vec![0.0, 1.0, 2.0]), "protocol {proto}");
            }
            assert_eq!(arr("f8").to_array2_f32().unwrap()[[1, 2]], 1.25);
            assert_eq!(arr("i4_3d_fortran").to_arrayd().unwrap()[[1, 2, 3]], 23.0);
        }
    }

    fn speech_dir() -> Option<std::path::PathBuf> {
        let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/haggling_speech"));
        if dir.is_dir() {
            Some(dir.to_path_buf())
        } else {
            crate::testing::skip_absent(dir, "real Haggling speech files");
            None
        }
    }

    fn real_files() -> Vec<(String, Vec<u8>)> {
        let Some(dir) = speech_dir() else { return Vec::new() };
        let mut files: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "pkl")).collect();
        files.sort();
        files.iter().map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(p).unwrap())).collect()
    }

    /// The six real Python-2 protocol-0 speech files parse into the documented structure.
    #[test]
    fn real_python2_speech_files_parse() {
        let files = real_files();
        for (name, bytes) in &files {
            let v = p(bytes);
            let frames = v.req_i64("endFrame").unwrap() - v.req_i64("startFrame").unwrap();
            let speech = v.req_list("speechData").unwrap();
            assert_eq!(speech.len(), 3, "{name}");
            for sp in speech {
                let ind = sp.req_array("indicator").unwrap();
                assert_eq!((ind.dtype, ind.ndim()), (DType::F8, 1), "{name}");
                assert!(ind.len() as i64 >= frames, "{name}");
                assert_eq!(sp.req_list("word").unwrap().len(), ind.len(), "{name}");
            }
        }
        if !files.is_empty() {
            assert_eq!(files.len(), 6);
        }
    }

    /// Applies one random mutation; returns a description for failure reports.
    fn mutate(rng: &mut rand::rngs::StdRng, b: &mut Vec<u8>) -> String {
        use rand::Rng;
        let n = b.len().max(1);
        match rng.gen_range(0..8) {
            0 => {
                let k = rng.gen_range(1..=4);
                for _ in 0..k {
                    let i = rng.gen_range(0..n).min(b.len().saturating_sub(1));
                    if let Some(x) = b.get_mut(i) {
                        *x = rng.gen();
                    }
                }
                format!("{k} byte flips")
            }
            1 => {
                let i = rng.gen_range(0..n);
                b.truncate(i);
                format!("truncated at {i}")
            }
            2 => {
                let i = rng.gen_range(0..=b.len());
                let len = rng.gen_range(1..16);
                let run: Vec<u8> = (0..len).map(|_| rng.gen()).collect();
                b.splice(i..i, run);
                format!("inserted {len} random bytes at {i}")
            }
            3 => {
                let i = rng.gen_range(0..n).min(b.len());
                let j = (i + rng.gen_range(1..64)).min(b.len());
                b.drain(i..j);
                format!("deleted {i}..{j}")
            }
            4 => {
                // Opcodes with huge length / count fields.
                let huge: [&[u8]; 9] = [
                    b"X\xff\xff\xff\x7f",
                    b"T\xff\xff\xff\x7f",
                    b"B\xff\xff\xff\xff",
                    b"\x8e\xff\xff\xff\xff\xff\xff\xff\x7f",
                    b"\x96\x00\x00\x00\x00\x00\x10\x00\x00",
                    b"\x95\xff\xff\xff\xff\xff\xff\xff\xff",
                    b"\x8b\xff\xff\xff\x7f",
                    b"j\xff\xff\xff\xff",
                    b"(I1000000000000\nI1000000\nt",
                ];
                let h = huge[rng.gen_range(0..huge.len())];
                let i = rng.gen_range(0..=b.len());
                b.splice(i..i, h.iter().copied());
                format!("inserted {:?} at {i}", String::from_utf8_lossy(h))
            }
            5 => {
                // Replace a decimal number (shapes, lengths, memo indices) by a huge one.
                let start = rng.gen_range(0..n);
                let Some(i) = b.iter().skip(start).position(u8::is_ascii_digit).map(|k| k + start) else {
                    return "no digits".into();
                };
                let j = b[i..].iter().position(|c| !c.is_ascii_digit()).map_or(b.len(), |k| i + k);
                let big = ["1000000000000", "18446744073709551616", "4294967296", "99999999999999999999999", "0"][rng.gen_range(0..5)];
                b.splice(i..j, big.bytes());
                format!("number at {i} replaced by {big}")
            }
            6 => {
                // Copy a chunk of the file elsewhere (duplicated opcodes, memo references).
                let i = rng.gen_range(0..n).min(b.len());
                let j = (i + rng.gen_range(1..200)).min(b.len());
                let chunk = b[i..j].to_vec();
                let k = rng.gen_range(0..=b.len());
                b.splice(k..k, chunk);
                format!("copied {i}..{j} to {k}")
            }
            _ => {
                let i = rng.gen_range(0..n).min(b.len());
                let ops = b"()]}tdlsaeubR0122gphq\x85\x86\x87\x93\x94.";
                let len = rng.gen_range(1..8);
                let run: Vec<u8> = (0..len).map(|_| ops[rng.gen_range(0..ops.len())]).collect();
                b.splice(i..i, run);
                format!("inserted {len} structural opcodes at {i}")
            }
        }
    }

    /// Seeded mutations of the real speech files and the NumPy and Python-3 body fixtures (about
    /// 14,000 mutants: byte flips, truncations, inserted / deleted / copied runs, huge length
    /// fields, huge numbers, stray structural opcodes): parsing must never
    /// panic (errors are fine); a panic reports the mutation and seed.
    #[test]
    fn fuzz_mutated_pickles_never_panic() {
        use rand::SeedableRng;
        let mut inputs = real_files();
        let fixtures = (0..=5).map(|p| format!("numpy_p{p}.pkl")).chain(["body_p2.pkl".into(), "body_p4.pkl".into()]);
        for name in fixtures {
            inputs.push((name.clone(), std::fs::read(fixture(&name)).unwrap()));
        }
        let start = std::time::Instant::now();
        let (mut parsed, mut failed) = (0usize, 0usize);
        for (idx, (name, original)) in inputs.iter().enumerate() {
            // The large real files take longer per parse: fewer rounds.
            let rounds = if original.len() > 30_000 { 400 } else { 1500 };
            for round in 0..rounds {
                let seed = (idx as u64) << 32 | round as u64;
                let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
                let mut b = original.clone();
                let mut what = Vec::new();
                for _ in 0..rand::Rng::gen_range(&mut rng, 1..=3) {
                    what.push(mutate(&mut rng, &mut b));
                }
                let r = std::panic::catch_unwind(|| parse_pickle(&b).is_ok());
                match r {
                    Ok(true) => parsed += 1,
                    Ok(false) => failed += 1,
                    Err(_) => panic!("parse_pickle panicked on {name} mutated with seed {seed}: {what:?}"),
                }
            }
        }
        eprintln!("fuzz: {parsed} mutants parsed, {failed} rejected, {:.1?}", start.elapsed());
    }

    #[test]
    fn unknown_globals_are_refused() {
        let e = err(b"cos\nsystem\n(S'echo hi'\ntR.");
        assert!(e.contains("unknown global os.system"), "{e}");
        assert!(e.contains("offset 0") && e.contains("GLOBAL"), "{e}");
        let e = err(b"\x80\x04\x8c\x08builtins\x94\x8c\x04eval\x94\x93.");
        assert!(e.contains("unknown global builtins.eval"), "{e}");
        assert!(err(b"ccopy_reg\n_reconstructor\n.").contains("copy_reg._reconstructor"));
    }

    #[test]
    fn malformed_input_is_an_error() {
        assert!(err(b"").contains("without a STOP"));
        assert!(err(b"I1\n").contains("without a STOP"));
        assert!(err(b".").contains("underflow"));
        assert!(err(b"a.").contains("underflow"));
        assert!(err(b"I1\nI2\na.").contains("APPEND on a int"));
        assert!(err(b"t.").contains("no MARK"));
        assert!(err(b"g3\n.").contains("memo index 3"));
        assert!(err(b"(I1\nd.").contains("odd number"));
        assert!(err(b"I1\n(a.").contains("underflow"));
        assert!(err(b"\xff.").contains("unknown opcode"));
        assert!(err(b"X\xff\xff\xff\xff.").contains("remain"));
        assert!(err(b"\x8d\xff\xff\xff\xff\xff\xff\xff\xff.").contains("remain"));
        assert!(err(b"\x8e\x00\x00\x00\x00\x00\x00\x00\x01.").contains("remain"));
        assert!(err(b"T\xff\xff\xff\xff.").contains("negative"));
        assert!(err(b"Ix\n.").contains("bad integer"));
        assert!(err(b"I1").contains("newline"));
        assert!(err(b"K\x01K\x02R.").contains("cannot call"));
        assert!(err(b"P1\n.").contains("persistent"));
        let e = Error::invalid("x").in_file("f.pkl").to_string();
        assert!(e.starts_with("f.pkl"));
    }

    #[test]
    fn hostile_structures_fail_cleanly() {
        // 100k nested lists: depth limit, no stack overflow.
        let n = 100_000;
        let mut b = vec![b']'; n];
        b.extend(vec![b'a'; n - 1]);
        b.push(b'.');
        assert!(err(&b).contains("nested deeper"));
        // Self-referencing list.
        assert!(err(b"]q\x00h\x00a.").contains("nested deeper"));
        // Billion laughs: each level doubles the previous one by reference.
        let mut b = vec![0x8c, 4, b'l', b'o', b'l', b'!', 0x94];
        for i in 0..40u8 {
            b.extend([b'h', i, b'h', i, 0x86, 0x94]);
        }
        b.push(b'.');
        assert!(err(&b).contains("expands to more than"));
        // 200k MARKs and a huge frame claim.
        let mut b = vec![b'('; 200_000];
        b.push(b'.');
        assert!(err(&b).contains("underflow"));
    }

    #[test]
    fn accessors_name_the_key() {
        let v = p(b"(dp0\nS'n'\nI3\nsS's'\nS'x'\nsS'f'\nF2.5\ns.");
        assert_eq!(v.req_i64("n").unwrap(), 3);
        assert_eq!(v.req_f64("n").unwrap(), 3.0);
        assert_eq!(v.req_f64("f").unwrap(), 2.5);
        assert_eq!(v.req_str("s").unwrap(), "x");
        let e = v.req_i64("s").unwrap_err().to_string();
        assert!(e.contains("\"s\"") && e.contains("str"), "{e}");
        assert!(v.req("zz").unwrap_err().to_string().contains("missing key \"zz\""));
        assert!(v.req_array("n").unwrap_err().to_string().contains("numpy array"));
        assert!(Value::Int(1).req("a").is_err());
    }

    #[test]
    fn read_pickle_names_the_file() {
        let dir = std::env::temp_dir().join(format!("socdiff-pickle-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("bad.pkl");
        std::fs::write(&f, b"I1\n").unwrap();
        let e = read_pickle(&f).unwrap_err();
        assert!(matches!(e, Error::Format { .. }) && e.to_string().contains("bad.pkl"), "{e}");
        let e = read_pickle(&dir.join("missing.pkl")).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
