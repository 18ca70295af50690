//! The state line's hash: FNV-1a over the bits of a displacement field. The emulator prints it
//! and `palpate-lab m4-emu compare` recomputes it on the host's field, so both include this one
//! file (the lab by `#[path]`): two copies could drift apart and report a difference that is
//! only in the hash.

/// FNV-1a (64-bit) over the little-endian bytes of every f32 of `u`.
pub fn fnv1a(u: &[f32]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for x in u {
        for b in x.to_bits().to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    h
}
