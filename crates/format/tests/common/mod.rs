//! Helpers shared by the format crate's integration tests.

/// Recomputes every section checksum and the header checksum after a byte-level edit.
pub fn reseal(bytes: &mut [u8]) {
    let count = u32::from_le_bytes(bytes[20..24].try_into().expect("8 or 4 bytes")) as usize;
    let table = u64::from_le_bytes(bytes[24..32].try_into().expect("8 or 4 bytes")) as usize;
    for i in 0..count {
        let at = table + 48 * i;
        let offset = u64::from_le_bytes(bytes[at + 8..at + 16].try_into().expect("8 or 4 bytes")) as usize;
        let length = u64::from_le_bytes(bytes[at + 16..at + 24].try_into().expect("8 or 4 bytes")) as usize;
        let crc = crc32fast::hash(&bytes[offset..offset + length]);
        bytes[at + 36..at + 40].copy_from_slice(&crc.to_le_bytes());
    }
    let mut crc = crc32fast::Hasher::new();
    crc.update(&bytes[..60]);
    crc.update(&[0; 4]);
    crc.update(&bytes[table..table + 48 * count]);
    let sum = crc.finalize();
    bytes[60..64].copy_from_slice(&sum.to_le_bytes());
}
