//! The mutations a fuzz case applies to its seed, and the strategies that draw them.

use super::*;

/// An interesting value written over bytes of the input.
#[derive(Clone, Copy, Debug)]
pub enum Value {
    U8(u8),
    U16(u16),
    U32(u32),
    U64(u64),
    F32(f32),
    F64(f64),
}

pub(super) fn interesting() -> impl Strategy<Value = (Value, bool)> {
    let v = prop_oneof![
        prop::sample::select(vec![0u8, 1, 0x7f, 0x80, 0xff]).prop_map(Value::U8),
        prop::sample::select(vec![0u16, 1, 0x7fff, 0x8000, 0xffff]).prop_map(Value::U16),
        prop::sample::select(vec![
            0u32,
            1,
            2,
            0x7fff_ffff,
            0x8000_0000,
            0xffff_ffff,
            65_536,
            1 << 20,
            1 << 28
        ])
        .prop_map(Value::U32),
        prop::sample::select(vec![0u64, u64::MAX, 1 << 32, 1 << 40, i64::MAX as u64]).prop_map(Value::U64),
        prop::sample::select(vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -1.0,
            0.0,
            -0.0,
            f32::MAX,
            f32::MIN_POSITIVE,
            1e-45
        ])
        .prop_map(Value::F32),
        prop::sample::select(vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -1.0, f64::MAX, 1e-320])
            .prop_map(Value::F64),
    ];
    (v, any::<bool>())
}

pub(super) fn value_bytes(v: Value, big_endian: bool) -> Vec<u8> {
    macro_rules! b {
        ($x:expr) => {
            if big_endian {
                $x.to_be_bytes().to_vec()
            } else {
                $x.to_le_bytes().to_vec()
            }
        };
    }
    match v {
        Value::U8(x) => vec![x],
        Value::U16(x) => b!(x),
        Value::U32(x) => b!(x),
        Value::U64(x) => b!(x),
        Value::F32(x) => b!(x),
        Value::F64(x) => b!(x),
    }
}

/// Tokens that text formats (OBJ, TOML, JSON, the Radiance header) must survive.
const TOKENS: &[&str] = &[
    "NaN",
    "nan",
    "inf",
    "-inf",
    "1e309",
    "-1e309",
    "-1",
    "-0",
    "0",
    "1e-320",
    "4294967296",
    "18446744073709551616",
    "9223372036854775807",
    "-9223372036854775808",
    "99999999999999999999",
    "0x10",
    "\"",
    "'",
    "\\",
    "\n",
    "\r\n",
    "\t",
    "\0",
    "[",
    "]",
    "{",
    "}",
    ",",
    ":",
    "=",
    "#",
    "/",
    "//",
    "f",
    "v",
    "vn",
    "vt",
    "usemtl",
    "mtllib ../../../etc/passwd",
    "g",
    "o",
    "-Y +X 999999999",
    "FORMAT=32-bit_rle_rgbe",
    "é",
    "\u{feff}",
    "[[",
    "null",
    "true",
    "{}",
    "[]",
];

/// One change to the bytes of a seed.
#[derive(Clone, Debug)]
pub enum Mutation {
    Flip {
        at: Index,
        bit: u8,
    },
    Set {
        at: Index,
        byte: u8,
    },
    Overwrite {
        at: Index,
        value: Value,
        big_endian: bool,
    },
    Truncate {
        at: Index,
    },
    Delete {
        at: Index,
        len: u16,
    },
    Insert {
        at: Index,
        bytes: Vec<u8>,
    },
    /// A chunk of the input repeated many times in place: huge counts, enormous arrays.
    Repeat {
        at: Index,
        len: u8,
        times: u16,
    },
    Token {
        at: Index,
        token: Index,
    },
    /// The n-th run of ASCII digits (with sign, dot, exponent) replaced by a token.
    Number {
        nth: Index,
        token: Index,
    },
    /// An opening bracket repeated: deeply nested TOML/JSON.
    Nest {
        at: Index,
        open: u8,
        depth: u32,
    },
}

/// Positions drawn this way land in the first 512 bytes half of the time: headers are where
/// binary formats keep their sizes and counts.
pub(super) fn position(len: usize, at: &Index, head_bias: bool) -> usize {
    if len == 0 {
        return 0;
    }
    if head_bias && at.index(2) == 0 {
        at.index(len.min(512))
    } else {
        at.index(len)
    }
}

pub(super) fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        3 => (any::<Index>(), 0u8..8).prop_map(|(at, bit)| Mutation::Flip { at, bit }),
        2 => (any::<Index>(), any::<u8>()).prop_map(|(at, byte)| Mutation::Set { at, byte }),
        3 => (any::<Index>(), interesting()).prop_map(|(at, (value, big_endian))| Mutation::Overwrite { at, value, big_endian }),
        1 => any::<Index>().prop_map(|at| Mutation::Truncate { at }),
        1 => (any::<Index>(), 1u16..512).prop_map(|(at, len)| Mutation::Delete { at, len }),
        1 => (any::<Index>(), prop::collection::vec(any::<u8>(), 1..16)).prop_map(|(at, bytes)| Mutation::Insert { at, bytes }),
        1 => (any::<Index>(), 1u8..64, 2u16..2000).prop_map(|(at, len, times)| Mutation::Repeat { at, len, times }),
        3 => (any::<Index>(), any::<Index>()).prop_map(|(at, token)| Mutation::Token { at, token }),
        3 => (any::<Index>(), any::<Index>()).prop_map(|(nth, token)| Mutation::Number { nth, token }),
        1 => (any::<Index>(), prop::sample::select(vec![b'[', b'{']), prop_oneof![1u32..64, 1000u32..200_000])
            .prop_map(|(at, open, depth)| Mutation::Nest { at, open, depth }),
    ]
}

/// Spans of ASCII numbers in `bytes`.
pub(super) fn numbers(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i].is_ascii_digit() {
            let start = if i > 0 && bytes[i - 1] == b'-' { i - 1 } else { i };
            let mut j = i;
            while j < bytes.len() && (bytes[j].is_ascii_digit() || matches!(bytes[j], b'.' | b'e' | b'E' | b'+' | b'-'))
            {
                j += 1;
            }
            out.push((start, j));
            i = j;
        } else {
            i += 1;
        }
    }
    out
}

/// The seed with the mutations applied in order.
pub fn apply(seed: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for m in mutations {
        let len = b.len();
        match m {
            Mutation::Flip { at, bit } if len > 0 => {
                let i = position(len, at, true);
                b[i] ^= 1 << bit;
            }
            Mutation::Set { at, byte } if len > 0 => {
                let i = position(len, at, true);
                b[i] = *byte;
            }
            Mutation::Overwrite { at, value, big_endian } => {
                let v = value_bytes(*value, *big_endian);
                let i = position(len, at, true);
                for (k, x) in v.into_iter().enumerate() {
                    if i + k < b.len() {
                        b[i + k] = x;
                    } else {
                        b.push(x);
                    }
                }
            }
            Mutation::Truncate { at } => b.truncate(position(len, at, false)),
            Mutation::Delete { at, len: n } if len > 0 => {
                let i = position(len, at, false);
                let end = (i + *n as usize).min(len);
                b.drain(i..end);
            }
            Mutation::Insert { at, bytes } => {
                let i = position(len + 1, at, false);
                b.splice(i..i, bytes.iter().copied());
            }
            Mutation::Repeat { at, len: n, times } if len > 0 => {
                let i = position(len, at, false);
                let end = (i + *n as usize).min(len);
                let chunk = b[i..end].to_vec();
                let extra: Vec<u8> = chunk
                    .iter()
                    .copied()
                    .cycle()
                    .take(chunk.len() * *times as usize)
                    .collect();
                b.splice(end..end, extra);
            }
            Mutation::Token { at, token } => {
                let t = TOKENS[token.index(TOKENS.len())].as_bytes();
                let i = position(len + 1, at, false);
                b.splice(i..i, t.iter().copied());
            }
            Mutation::Number { nth, token } => {
                let spans = numbers(&b);
                if !spans.is_empty() {
                    let (s, e) = spans[nth.index(spans.len())];
                    let t = TOKENS[token.index(TOKENS.len())].as_bytes();
                    b.splice(s..e, t.iter().copied());
                }
            }
            Mutation::Nest { at, open, depth } => {
                let i = position(len + 1, at, false);
                b.splice(i..i, std::iter::repeat_n(*open, *depth as usize));
            }
            _ => {}
        }
    }
    b
}
