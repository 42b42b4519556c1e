//! Byte edits of a valid input, for the fuzz tests of both crates that parse bytes (saved
//! states and URDF text in `equigym-envs`, policy files in `equigym-wrappers`): proptest draws a
//! few edits, [`apply`] makes them. Included by path from each crate's `tests/fuzz.rs`.

use proptest::prelude::*;

/// One byte edit; positions are taken modulo the length they apply to.
#[derive(Clone, Debug)]
pub enum Edit {
    Set(usize, u8),
    Truncate(usize),
    Insert(usize, u8),
    Remove(usize),
}

/// Between 1 and `max_edits - 1` edits, drawn with the relative `weights` of set, truncate,
/// insert and remove.
pub fn edits(weights: [u32; 4], max_edits: usize) -> impl Strategy<Value = Vec<Edit>> {
    let [set, truncate, insert, remove] = weights;
    let edit = prop_oneof![
        set => (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Edit::Set(i, b)),
        truncate => any::<usize>().prop_map(Edit::Truncate),
        insert => (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Edit::Insert(i, b)),
        remove => any::<usize>().prop_map(Edit::Remove),
    ];
    proptest::collection::vec(edit, 1..max_edits)
}

/// `bytes` with `edits` made in order, each within the first `focus` bytes (`usize::MAX`:
/// anywhere).
pub fn apply(bytes: &[u8], focus: usize, edits: &[Edit]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    for e in edits {
        let n = out.len().clamp(1, focus.max(1));
        match *e {
            Edit::Set(i, b) if !out.is_empty() => out[i % n] = b,
            Edit::Truncate(i) => out.truncate(i % n),
            Edit::Insert(i, b) => out.insert(i % (n.min(out.len()) + 1), b),
            Edit::Remove(i) if !out.is_empty() => {
                out.remove(i % n);
            }
            _ => {}
        }
    }
    out
}
