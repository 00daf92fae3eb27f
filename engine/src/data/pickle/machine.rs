//! The pickle machine: opcodes, the stack, the memo, and the arena that holds containers.

use super::numpy::{build_array, decode_array, dtype_state_order, parse_shape, raw_bytes, ByteOrder, DType};
use super::text::{escape_decode, int_from_le, latin1, latin1_encode, parse_decimal, raw_unicode_escape, truncate};
use super::value::{Object, Value};
use super::MAX_DEPTH;
use std::collections::HashMap;

// ---------------------------------------------------------------------------------------------
// The machine.
//
// Containers and memoized values live in an arena (`slots`); the stack and containers hold
// `Item`s, which are either inline scalars or references to slots. Mutating opcodes (APPEND,
// SETITEM, BUILD, ...) mutate the slot, so every reference sees the change, as in Python. Nothing
// is nested while reading, so no recursion or deep drop can happen; the result is expanded into a
// tree of `Value`s once, at STOP, under a depth limit and a memory budget.

pub(super) type Res<T> = std::result::Result<T, String>;

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
    ObjectDtype,
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
pub(super) struct Budget {
    left: usize,
    limit: usize,
}

impl Budget {
    pub(super) fn charge(&mut self, bytes: usize) -> Res<()> {
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

pub(super) struct Machine<'a> {
    data: &'a [u8],
    pos: usize,
    stack: Vec<Item>,
    marks: Vec<usize>,
    memo: HashMap<u64, usize>,
    slots: Vec<Node>,
    budget: Budget,
}

impl<'a> Machine<'a> {
    pub(super) fn new(data: &'a [u8]) -> Self {
        // Generous for real files (which expand a few times at most), small enough that a
        // hostile file cannot exhaust memory.
        let limit = data.len().saturating_mul(64).saturating_add(1 << 20);
        Self { data, pos: 0, stack: Vec::new(), marks: Vec::new(), memo: HashMap::new(), slots: Vec::new(), budget: Budget { left: limit, limit } }
    }

    pub(super) fn run(mut self) -> Res<Value> {
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
            Node::ObjectDtype => "object dtype",
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
                        self.slots[s] = Node::Leaf(match zero_d_object(&state)? {
                            Some(element) => element,
                            None => Value::NdArray(build_array(&state, &mut self.budget)?),
                        });
                    }
                    // An object dtype's state says nothing an object array needs.
                    Node::ObjectDtype => {}
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
                if matches!(descr, "O" | "O4" | "O8" | "object") {
                    return Ok(Node::ObjectDtype);
                }
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
        Node::ObjectDtype => Value::Object(Object::ObjectDtype),
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

/// The element of a 0-d object array's `ndarray.__setstate__` state (`np.save` of a dict, as
/// VideoPose3D's `.npz` holds), or `None` for a numeric array. Object arrays of any other shape
/// are refused.
fn zero_d_object(state: &Value) -> Res<Option<Value>> {
    let Some(items) = state.as_list() else { return Ok(None) };
    let (shape, dtype, data) = match items {
        [Value::Int(_), s, d, _, r] | [s, d, _, r] => (s, d, r),
        _ => return Ok(None),
    };
    if !matches!(dtype, Value::Object(Object::ObjectDtype)) {
        return Ok(None);
    }
    match (parse_shape(shape)?.as_slice(), data.as_list()) {
        ([], Some([element])) => Ok(Some(element.clone())),
        _ => Err("object arrays (dtype 'O') are supported only as a single 0-d element".into()),
    }
}
