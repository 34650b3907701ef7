//! Payloads over zenoh and to the page: the renderer contract's `repr(C)` values as bytes
//! (docs/ipc.md layouts, little-endian), a slice service as its user header then its elements.

/// Raw bytes of a `repr(C)` value of the renderer contract.
pub fn bytes_of<T: Copy>(value: &T) -> &[u8] {
    // SAFETY: only used with the contract's repr(C) types, which have no padding (docs/ipc.md;
    // ipc/tests/layout_matches_docs.rs), so every byte is initialised; the slice borrows `value`.
    unsafe { core::slice::from_raw_parts((value as *const T).cast::<u8>(), size_of::<T>()) }
}

/// Raw bytes of a slice of padding-free elements (u8, u32, f32, `Particle`).
pub fn slice_bytes<T: Copy>(values: &[T]) -> &[u8] {
    // SAFETY: as in `bytes_of`; the length is the slice's size in bytes.
    unsafe { core::slice::from_raw_parts(values.as_ptr().cast::<u8>(), size_of_val(values)) }
}

/// A copy of a contract value from bytes, if the length is exact.
pub fn read_exact<T: Copy>(bytes: &[u8]) -> Option<T> {
    (bytes.len() == size_of::<T>()).then(|| {
        // SAFETY: the length is checked; the contract's types are plain integers and floats, for
        // which every bit pattern is valid; read_unaligned allows any alignment.
        unsafe { core::ptr::read_unaligned(bytes.as_ptr().cast::<T>()) }
    })
}

/// Elements from bytes; `None` unless the length is a whole number of elements.
pub fn read_slice<T: Copy>(bytes: &[u8]) -> Option<Vec<T>> {
    let size = size_of::<T>();
    if size == 0 || !bytes.len().is_multiple_of(size) {
        return None;
    }
    Some(bytes.chunks_exact(size).filter_map(read_exact).collect())
}

/// A slice sample as one payload: the header's bytes, then the elements'.
pub fn encode_slice<H: Copy, E: Copy>(header: &H, elements: &[E]) -> Vec<u8> {
    let mut out = Vec::with_capacity(size_of::<H>() + size_of_val(elements));
    out.extend_from_slice(bytes_of(header));
    out.extend_from_slice(slice_bytes(elements));
    out
}

/// The header and elements of a payload made by [`encode_slice`].
pub fn decode_slice<H: Copy, E: Copy>(bytes: &[u8]) -> Option<(H, Vec<E>)> {
    let h = bytes.get(..size_of::<H>()).and_then(read_exact::<H>)?;
    let e = read_slice::<E>(&bytes[size_of::<H>()..])?;
    Some((h, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use hydrometra_ipc::mesh::MeshPositionsHeader;
    use hydrometra_ipc::Status;

    #[test]
    fn a_status_round_trips_and_a_wrong_length_is_refused() {
        let s = Status {
            sequence: 9,
            cavity_pressure_pa: 1234.5,
            ..Status::default()
        };
        let b = bytes_of(&s).to_vec();
        assert_eq!(b.len(), 752); // docs/ipc.md
        let back: Status = read_exact(&b).unwrap();
        assert_eq!((back.sequence, back.cavity_pressure_pa), (9, 1234.5));
        assert!(read_exact::<Status>(&b[1..]).is_none());
    }

    #[test]
    fn slices_round_trip_and_ragged_payloads_are_refused() {
        let h = MeshPositionsHeader {
            vertex_count: 2,
            topology_revision: 5,
            ..Default::default()
        };
        let p = encode_slice(&h, &[1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let hb = size_of::<MeshPositionsHeader>();
        assert_eq!(p.len(), hb + 24);
        let (h2, e): (MeshPositionsHeader, Vec<f32>) = decode_slice(&p).unwrap();
        assert_eq!(h2.topology_revision, 5);
        assert_eq!(e, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        assert!(decode_slice::<MeshPositionsHeader, f32>(&p[..hb + 1]).is_none());
        assert!(decode_slice::<MeshPositionsHeader, f32>(&p[..10]).is_none());
    }
}
