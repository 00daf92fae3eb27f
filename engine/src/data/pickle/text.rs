//! Python's integer and string codecs as pickles use them.

use super::machine::Res;
use super::value::Value;

/// Parses a protocol-0 decimal integer (Python's `int()`: surrounding whitespace allowed).
pub(super) fn parse_decimal(l: &[u8]) -> Res<Value> {
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
pub(super) fn int_from_le(b: &[u8]) -> Value {
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

pub(super) fn latin1(b: &[u8]) -> String {
    b.iter().map(|&c| c as char).collect()
}

pub(super) fn latin1_encode(s: &str) -> Res<Vec<u8>> {
    s.chars().map(|c| u8::try_from(c as u32).map_err(|_| format!("character U+{:04X} cannot be encoded as latin-1", c as u32))).collect()
}

/// Python's `codecs.escape_decode` (the body of a protocol-0 `STRING`).
pub(super) fn escape_decode(s: &[u8]) -> Res<Vec<u8>> {
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
pub(super) fn raw_unicode_escape(s: &[u8]) -> Res<String> {
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

/// The first 40 bytes of `b`, for messages.
pub(super) fn truncate(b: &[u8]) -> String {
    let s = String::from_utf8_lossy(&b[..b.len().min(40)]).into_owned();
    if b.len() > 40 {
        s + "..."
    } else {
        s
    }
}
