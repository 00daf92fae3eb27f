//! NumPy `.npy` files (format versions 1–3), read and written without numpy.
//!
//! Readers take untrusted files: the header's shape must account for exactly the bytes that
//! follow it, so a header claiming 10¹² elements is an error, never an allocation.

use crate::{Error, Result};
use std::io::Write;
use std::path::Path;

const MAGIC: &[u8] = b"\x93NUMPY";

/// Element data of an `.npy` file, converted to native byte order.
#[derive(Clone, Debug, PartialEq)]
pub enum NpyData {
    /// `f4`
    F32(Vec<f32>),
    /// `f8`
    F64(Vec<f64>),
    /// `u1` or `b1`
    U8(Vec<u8>),
    /// `i8`, `i4`, `i2`, `i1`, `u8`, `u4`, `u2` (widened)
    I64(Vec<i64>),
}

/// An array read from `.npy`, in C order.
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

/// Parses `.npy` bytes.
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(Error::invalid("not a .npy file (bad magic)"));
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10usize),
        2 | 3 if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        v => return Err(Error::invalid(format!(".npy format version {v} is not supported"))),
    };
    let end = start.checked_add(header_len).filter(|&e| e <= bytes.len()).ok_or_else(|| Error::invalid(".npy header is truncated"))?;
    let header = std::str::from_utf8(&bytes[start..end]).map_err(|_| Error::invalid(".npy header is not text"))?;
    let descr = header_field(header, "descr")?;
    let descr = descr.trim_matches(|c| c == '\'' || c == '"').to_string();
    let fortran = header_field(header, "fortran_order")?;
    let fortran = match fortran {
        "True" => true,
        "False" => false,
        other => return Err(Error::invalid(format!(".npy header: fortran_order {other:?}"))),
    };
    let shape = parse_shape(header_field(header, "shape")?)?;
    let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or_else(|| Error::invalid(format!(".npy shape {shape:?} overflows")))?;
    let body = &bytes[end..];
    let (little, kind, size) = parse_descr(&descr)?;
    if count.checked_mul(size) != Some(body.len()) {
        return Err(Error::invalid(format!(".npy shape {shape:?} of {descr} needs {} bytes of data, the file has {}", count.saturating_mul(size), body.len())));
    }
    let word = |i: usize| -> [u8; 8] {
        let mut w = [0u8; 8];
        let src = &body[i * size..(i + 1) * size];
        if little {
            w[..size].copy_from_slice(src);
        } else {
            for (k, b) in src.iter().rev().enumerate() {
                w[k] = *b;
            }
        }
        w
    };
    let data = match (kind, size) {
        ('f', 4) => NpyData::F32((0..count).map(|i| f32::from_le_bytes(word(i)[..4].try_into().unwrap())).collect()),
        ('f', 8) => NpyData::F64((0..count).map(|i| f64::from_le_bytes(word(i))).collect()),
        ('u' | 'b', 1) => NpyData::U8(body.to_vec()),
        ('i', 1 | 2 | 4 | 8) => NpyData::I64(
            (0..count)
                .map(|i| {
                    let shift = 64 - 8 * size as u32;
                    (i64::from_le_bytes(word(i)) << shift) >> shift
                })
                .collect(),
        ),
        ('u', 2 | 4) => NpyData::I64((0..count).map(|i| i64::from_le_bytes(word(i))).collect()),
        _ => return Err(Error::invalid(format!(".npy dtype {descr} is not supported"))),
    };
    let data = if fortran { to_c_order(data, &shape) } else { data };
    Ok(NpyArray { shape, descr, data })
}

/// Finds `'key': value` in a header dict; returns the raw value text.
fn header_field<'a>(header: &'a str, key: &str) -> Result<&'a str> {
    let pat = format!("'{key}':");
    let at = header.find(&pat).ok_or_else(|| Error::invalid(format!(".npy header has no {key}")))?;
    let rest = header[at + pat.len()..].trim_start();
    let len = if rest.starts_with('(') { rest.find(')').map(|i| i + 1) } else { rest.find([',', '}']) }
        .ok_or_else(|| Error::invalid(format!(".npy header: unterminated {key}")))?;
    Ok(rest[..len].trim())
}

fn parse_shape(s: &str) -> Result<Vec<usize>> {
    let inner = s.strip_prefix('(').and_then(|s| s.strip_suffix(')')).ok_or_else(|| Error::invalid(format!(".npy shape {s:?}")))?;
    inner
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| t.trim_end_matches('L').parse::<usize>().map_err(|_| Error::invalid(format!(".npy shape {s:?}"))))
        .collect()
}

/// (little endian, kind char, item size) of a descr like `<f4`.
fn parse_descr(d: &str) -> Result<(bool, char, usize)> {
    let b = d.as_bytes();
    if b.len() < 3 {
        return Err(Error::invalid(format!(".npy dtype {d:?} is not supported")));
    }
    let little = match b[0] {
        b'<' | b'|' | b'=' => true,
        b'>' => false,
        _ => return Err(Error::invalid(format!(".npy dtype {d:?} is not supported"))),
    };
    let size: usize = d[2..].parse().map_err(|_| Error::invalid(format!(".npy dtype {d:?} is not supported")))?;
    if !(1..=8).contains(&size) {
        return Err(Error::invalid(format!(".npy dtype {d:?} is not supported")));
    }
    Ok((little, b[1] as char, size))
}

fn to_c_order(data: NpyData, shape: &[usize]) -> NpyData {
    // Fortran order = C order of the reversed shape; transpose by index arithmetic.
    fn permute<T: Copy>(v: Vec<T>, shape: &[usize]) -> Vec<T> {
        let n = v.len();
        let mut out = Vec::with_capacity(n);
        let mut idx = vec![0usize; shape.len()];
        for _ in 0..n {
            let (mut off, mut stride) = (0, 1);
            for (k, &d) in shape.iter().enumerate() {
                off += idx[k] * stride;
                stride *= d;
            }
            out.push(v[off]);
            for k in (0..shape.len()).rev() {
                idx[k] += 1;
                if idx[k] < shape[k] {
                    break;
                }
                idx[k] = 0;
            }
        }
        out
    }
    match data {
        NpyData::F32(v) => NpyData::F32(permute(v, shape)),
        NpyData::F64(v) => NpyData::F64(permute(v, shape)),
        NpyData::U8(v) => NpyData::U8(permute(v, shape)),
        NpyData::I64(v) => NpyData::I64(permute(v, shape)),
    }
}

/// Encodes a little-endian C-order `.npy` (version 1.0) of `descr` with the given raw bytes.
fn encode(descr: &str, shape: &[usize], raw: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_txt = if shape.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_txt}, }}");
    // Pad with spaces so that the data starts on a 64-byte boundary, newline-terminated.
    let pad = (64 - (10 + header.len() + 1) % 64) % 64;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + raw.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(raw);
    out
}

/// Writes a float32 array as `.npy`.
pub fn write_npy_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    debug_assert_eq!(shape.iter().product::<usize>(), data.len());
    let raw: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    write_file(path, &encode("<f4", shape, &raw))
}

/// Writes a uint8 array as `.npy`.
pub fn write_npy_u8(path: &Path, shape: &[usize], data: &[u8]) -> Result<()> {
    debug_assert_eq!(shape.iter().product::<usize>(), data.len());
    write_file(path, &encode("|u1", shape, data))
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut f = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    f.write_all(bytes).map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_header_alignment() {
        let dir = std::env::temp_dir().join(format!("socdiff-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.npy");
        let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.5 - 3.0).collect();
        write_npy_f32(&p, &[2, 3, 4], &data).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!((bytes.len() - data.len() * 4) % 64, 0);
        let a = read_npy(&p).unwrap();
        assert_eq!(a.shape, vec![2, 3, 4]);
        assert_eq!(a.into_f32(&p).unwrap(), data);
        write_npy_u8(&p, &[5], &[1, 0, 1, 1, 0]).unwrap();
        assert_eq!(read_npy(&p).unwrap().shape, vec![5]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn fortran_and_big_endian() {
        // [[1, 2, 3], [4, 5, 6]] stored in Fortran order as big-endian int16.
        let raw: Vec<u8> = [1i16, 4, 2, 5, 3, 6].iter().flat_map(|v| v.to_be_bytes()).collect();
        let mut bytes = encode(">i2", &[2, 3], &raw);
        let h = String::from_utf8_lossy(&bytes[10..]).replace("False", "True ");
        bytes.splice(10.., h.bytes());
        let a = parse_npy(&bytes).unwrap();
        assert_eq!(a.data, NpyData::I64(vec![1, 2, 3, 4, 5, 6]));
    }

    #[test]
    fn lying_headers_are_errors_not_allocations() {
        let huge = encode("<f4", &[1_000_000, 1_000_000], &[0u8; 16]);
        let e = parse_npy(&huge).unwrap_err().to_string();
        assert!(e.contains("needs 4000000000000 bytes"), "{e}");
        let overflow = encode("<f8", &[usize::MAX, 3], &[]);
        assert!(parse_npy(&overflow).unwrap_err().to_string().contains("overflows"));
        assert!(parse_npy(b"\x93NUMPY\x01\x00\xff\xff{").is_err());
        assert!(parse_npy(b"PK\x03\x04").is_err());
        assert!(parse_npy(&encode("<c16", &[1], &[0u8; 16])).is_err());
    }
}
