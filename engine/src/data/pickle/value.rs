//! The values a pickle yields: plain Python data and NumPy arrays.

use super::numpy::{ByteOrder, DType, NdArray};
use crate::{Error, Result};

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
    /// `numpy.dtype('O')`: the dtype of a 0-d object array (the only object arrays read).
    ObjectDtype,
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
            Value::Object(Object::ObjectDtype) => "object dtype",
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
