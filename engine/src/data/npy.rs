//! NumPy `.npy` files through `ndarray-npy`, with the checks an untrusted file needs.
//!
//! `ndarray-npy` allocates the element count its header claims before reading the data, so a
//! 100-byte file claiming 10¹² elements would abort the process. The header is therefore read
//! first and its shape must account for exactly the bytes that follow it; only then are the
//! elements decoded.

use crate::{Error, Result};
use ndarray::{ArrayD, ArrayViewD, IxDyn};
use ndarray_npy::npy::header::Header;
use ndarray_npy::{ReadNpyExt, ReadableElement, WritableElement, WriteNpyExt};
use std::path::Path;

/// Element data of an `.npy` file, in C order and native byte order.
#[derive(Clone, Debug, PartialEq)]
pub enum NpyData {
    /// `f4`
    F32(Vec<f32>),
    /// `f8`
    F64(Vec<f64>),
    /// `u1`, or `b1` as 0/1
    U8(Vec<u8>),
}

/// An array read from `.npy`.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    /// Dimensions.
    pub shape: Vec<usize>,
    /// The `descr` of the header, e.g. `<f4`.
    pub descr: String,
    /// Elements in C order.
    pub data: NpyData,
}

impl NpyArray {
    /// The elements as f32, if the dtype is `f4`; an error naming `path` otherwise.
    pub fn into_f32(self, path: &Path) -> Result<Vec<f32>> {
        match self.data {
            NpyData::F32(v) => Ok(v),
            _ => Err(Error::format(path, format!("dtype {} where float32 (<f4) was expected", self.descr))),
        }
    }

    /// The elements as u8, if the dtype is `u1` or `b1`; an error naming `path` otherwise.
    pub fn into_u8(self, path: &Path) -> Result<Vec<u8>> {
        match self.data {
            NpyData::U8(v) => Ok(v),
            _ => Err(Error::format(path, format!("dtype {} where uint8 (|u1) was expected", self.descr))),
        }
    }

    /// Checks the shape against `expected` (`None` = any size), naming `path` and `what`.
    pub fn expect_shape(&self, path: &Path, what: &str, expected: &[Option<usize>]) -> Result<()> {
        let ok = self.shape.len() == expected.len() && self.shape.iter().zip(expected).all(|(a, e)| e.is_none_or(|e| e == *a));
        if ok {
            return Ok(());
        }
        let want: Vec<String> = expected.iter().map(|e| e.map_or("*".to_string(), |e| e.to_string())).collect();
        Err(Error::format(path, format!("{what} has shape {:?}, expected [{}]", self.shape, want.join(", "))))
    }
}

/// Reads an `.npy` file.
pub fn read_npy(path: &Path) -> Result<NpyArray> {
    let bytes = crate::files::read_bounded(path, 16 << 30, ".npy file")?;
    parse_npy(&bytes).map_err(|e| e.in_file(path))
}

/// Parses `.npy` bytes (format versions 1–3; float32, float64, uint8 and bool elements).
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray> {
    let mut body = bytes;
    let header = Header::from_reader(&mut body).map_err(|e| Error::invalid(format!("not a readable .npy file: {e}")))?;
    let Some(descr) = header.type_descriptor.as_string().cloned() else {
        return Err(Error::invalid(format!(".npy dtype {} is not supported", header.type_descriptor)));
    };
    let size = match descr.as_str() {
        "<f4" | ">f4" => 4,
        "<f8" | ">f8" => 8,
        "|u1" | "u1" | "|b1" => 1,
        _ => return Err(Error::invalid(format!(".npy dtype {descr} is not supported (float32, float64, uint8 or bool)"))),
    };
    let shape = header.shape;
    let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or_else(|| Error::invalid(format!(".npy shape {shape:?} overflows")))?;
    if count.checked_mul(size) != Some(body.len()) {
        return Err(Error::invalid(format!(".npy shape {shape:?} of {descr} needs {} bytes of data, the file has {}", count.saturating_mul(size), body.len())));
    }
    let data = match size {
        4 => NpyData::F32(decode(bytes)?),
        8 => NpyData::F64(decode(bytes)?),
        _ if descr == "|b1" => NpyData::U8(decode::<bool>(bytes)?.into_iter().map(u8::from).collect()),
        _ => NpyData::U8(decode(bytes)?),
    };
    Ok(NpyArray { shape, descr, data })
}

/// The object a 0-d object `.npy` holds (`np.save` of a dict: its pickle, read by
/// [`crate::data::pickle`], which runs no code).
pub fn object_npy(bytes: &[u8]) -> Result<crate::data::pickle::Value> {
    let mut body = bytes;
    let header = Header::from_reader(&mut body).map_err(|e| Error::invalid(format!("not a readable .npy file: {e}")))?;
    let descr = header.type_descriptor.as_string().cloned().unwrap_or_default();
    if descr != "|O" || !header.shape.is_empty() {
        return Err(Error::invalid(format!(
            ".npy of dtype {} and shape {:?}: expected one pickled object (|O, shape ())",
            header.type_descriptor, header.shape
        )));
    }
    crate::data::pickle::parse_pickle(body)
}

/// Elements of a checked `.npy` in C order.
fn decode<T: ReadableElement + Clone>(bytes: &[u8]) -> Result<Vec<T>> {
    let array = ArrayD::<T>::read_npy(bytes).map_err(|e| Error::invalid(format!(".npy data: {e}")))?;
    Ok(if array.is_standard_layout() { array.into_raw_vec_and_offset().0 } else { array.iter().cloned().collect() })
}

/// Writes a float32 array as `.npy`.
pub fn write_npy_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    write_file(path, shape, data)
}

/// Writes a uint8 array as `.npy`.
pub fn write_npy_u8(path: &Path, shape: &[usize], data: &[u8]) -> Result<()> {
    write_file(path, shape, data)
}

fn write_file<T: WritableElement>(path: &Path, shape: &[usize], data: &[T]) -> Result<()> {
    let view = ArrayViewD::from_shape(IxDyn(shape), data)
        .map_err(|e| Error::invalid(format!("{}: shape {shape:?} for {} values: {e}", path.display(), data.len())))?;
    let mut bytes = Vec::new();
    view.write_npy(&mut bytes).map_err(|e| Error::io(path, std::io::Error::other(e)))?;
    // Through a fresh temporary file renamed into place: a symbolic link at `path` is replaced,
    // never followed.
    crate::files::write_file_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little `.npy` (version 1.0) with the header text `dict` and the raw `data`.
    fn npy(dict: &str, data: &[u8]) -> Vec<u8> {
        let mut header = dict.to_string();
        header.push_str(&" ".repeat((64 - (10 + header.len() + 1) % 64) % 64));
        header.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(data);
        out
    }

    #[test]
    fn round_trip_and_header_alignment() {
        let dir = std::env::temp_dir().join(format!("socdiff-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.npy");
        let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.5 - 3.0).collect();
        write_npy_f32(&p, &[2, 3, 4], &data).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!((bytes.len() - data.len() * 4) % 16, 0, "data starts aligned");
        let a = read_npy(&p).unwrap();
        assert_eq!((a.shape.clone(), a.descr.as_str()), (vec![2, 3, 4], "<f4"));
        assert_eq!(a.into_f32(&p).unwrap(), data);
        write_npy_u8(&p, &[5], &[1, 0, 1, 1, 0]).unwrap();
        let a = read_npy(&p).unwrap();
        assert_eq!((a.shape.clone(), a.into_u8(&p).unwrap()), (vec![5], vec![1, 0, 1, 1, 0]));
        assert!(write_npy_f32(&p, &[2, 2], &[1.0; 3]).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn fortran_big_endian_and_bool() {
        // [[1, 2, 3], [4, 5, 6]] stored in Fortran order as big-endian float32.
        let raw: Vec<u8> = [1f32, 4., 2., 5., 3., 6.].iter().flat_map(|v| v.to_be_bytes()).collect();
        let a = parse_npy(&npy("{'descr': '>f4', 'fortran_order': True, 'shape': (2, 3), }", &raw)).unwrap();
        assert_eq!(a.data, NpyData::F32(vec![1., 2., 3., 4., 5., 6.]));
        let b = parse_npy(&npy("{'descr': '|b1', 'fortran_order': False, 'shape': (3,), }", &[1, 0, 1])).unwrap();
        assert_eq!(b.data, NpyData::U8(vec![1, 0, 1]));
    }

    #[test]
    fn lying_headers_are_errors_not_allocations() {
        let huge = npy("{'descr': '<f4', 'fortran_order': False, 'shape': (1000000, 1000000), }", &[0u8; 16]);
        let e = parse_npy(&huge).unwrap_err().to_string();
        assert!(e.contains("needs 4000000000000 bytes"), "{e}");
        let overflow = npy(&format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({}, 3), }}", usize::MAX), &[]);
        let e = parse_npy(&overflow).unwrap_err().to_string();
        assert!(e.contains("overflows") || e.contains("not a readable"), "{e}");
        assert!(parse_npy(b"\x93NUMPY\x01\x00\xff\xff{").is_err());
        assert!(parse_npy(b"PK\x03\x04").is_err());
        let e = parse_npy(&npy("{'descr': '<c16', 'fortran_order': False, 'shape': (1,), }", &[0u8; 16])).unwrap_err().to_string();
        assert!(e.contains("not supported"), "{e}");
    }
}
