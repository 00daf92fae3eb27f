//! Tests of the pickle reader.

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
    let b =
        b"\x80\x02c__builtin__\nbytearray\nq\x00c_codecs\nencode\nq\x01X\x01\x00\x00\x00\x01q\x02X\x06\x00\x00\x00latin1q\x03\x86q\x04Rq\x05\x85q\x06Rq\x07.";
    assert_eq!(p(b), Value::Bytes(vec![1]));
    // The same dict as the protocol-2 one, with protocol 0 (UNICODE strings, set from a list).
    let b = b"(dp0\nVa\np1\nc_codecs\nencode\np2\n(V\\u0000\xff\np3\nVlatin1\np4\ntp5\nRp6\nsVb\np7\nc__builtin__\nset\np8\n((lp9\nI1\naI2\natp10\nRp11\ns.";
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
    // Unsupported dtypes are named; object arrays are read only as one 0-d element.
    assert!(err(&np0("I1\n", "U8", "|", "00", "")).contains("\"U8\""));
    assert!(err(&np0("I1\n", "O8", "|", "00", "")).contains("only as a single 0-d element"));
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
        let plain = Value::List(vec![Value::Int(1), s("two"), Value::Float(3.0), Value::None, Value::Tuple(vec![Value::Bool(true), Value::Bytes(vec![0, 1])])]);
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
