//! NumPy as pickles rebuild it: dtypes, byte orders, arrays widened to f64, and
//! `ndarray.__setstate__`.

use super::machine::{Budget, Res};
use super::text::latin1_encode;
use super::value::{Object, Value};
use crate::{Error, Result};

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

    pub(super) fn is_big(self) -> bool {
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

    /// One element's bytes, little-endian in the first `itemsize` bytes of a zeroed word.
    fn little_endian_word(self, b: &[u8], big: bool) -> [u8; 8] {
        let mut buf = [0u8; 8];
        let n = self.itemsize().min(b.len());
        buf[..n].copy_from_slice(&b[..n]);
        if big {
            buf[..n].reverse();
        }
        buf
    }

    /// Decodes one element of `self.itemsize()` bytes.
    fn decode(self, b: &[u8], big: bool) -> f64 {
        let buf = self.little_endian_word(b, big);
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
    pub(super) fn decode_scalar(self, b: &[u8], big: bool) -> Value {
        let buf = self.little_endian_word(b, big);
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

/// Raw array data from bytes, or from a latin-1 string (Python-2 pickles).
pub(super) fn raw_bytes(v: &Value) -> Res<Vec<u8>> {
    match v {
        Value::Bytes(b) => Ok(b.clone()),
        Value::Str(s) => latin1_encode(s),
        Value::List(_) | Value::Tuple(_) => Err("object arrays (dtype 'O') are not supported".into()),
        other => Err(format!("array data is a {}, expected bytes", other.type_name())),
    }
}

pub(super) fn parse_shape(v: &Value) -> Res<Vec<usize>> {
    let items = v.as_list().ok_or_else(|| format!("array shape is a {}, expected a tuple", v.type_name()))?;
    items
        .iter()
        .map(|d| match d {
            Value::Int(i) => usize::try_from(*i).map_err(|_| format!("negative array dimension {i}")),
            other => Err(format!("array dimension is a {}", other.type_name())),
        })
        .collect()
}

pub(super) fn decode_array(raw: &[u8], shape: Vec<usize>, dt: DType, order: ByteOrder, fortran: bool, budget: &mut Budget) -> Res<NdArray> {
    // The element count is checked against `raw.len()` before anything is allocated; the f64
    // copy is charged to the budget like any other expansion.
    budget.charge((raw.len() / dt.itemsize()).saturating_mul(8))?;
    NdArray::decode(raw, shape, dt, order, fortran)
}

/// The byte order in a dtype's `BUILD` state `(version, order, subarray, names, fields, ...)`.
pub(super) fn dtype_state_order(state: &Value) -> Res<ByteOrder> {
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
pub(super) fn build_array(state: &Value, budget: &mut Budget) -> Res<NdArray> {
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
