//! Loopback tests of the link against exact bytes, and the receiver under damage.

use super::*;
use proptest::prelude::*;

/// The example frame of `LINK-FORMAT.md`.
pub(crate) const EXAMPLE: ForceSample = ForceSample {
    seq: 1000,
    timestamp_us: 1_000_000,
    raw_counts: 12_345,
    force_n: 2.5,
    status: status::OK,
};

/// Its exact bytes on the wire, as written in `LINK-FORMAT.md` (derived by hand there).
pub(crate) const EXAMPLE_WIRE: [u8; 21] = [
    0x0B, 0x01, 0x02, 0xE8, 0x07, 0xC0, 0x84, 0x3D, 0xF2, 0xC0, 0x01, 0x01, 0x03, 0x20, 0x40, 0x05,
    0x25, 0xE2, 0xC6, 0x10, 0x00,
];

fn sample(seq: u32) -> ForceSample {
    ForceSample {
        seq,
        timestamp_us: u64::from(seq) * 1000,
        raw_counts: (seq % 30000) as i16,
        force_n: seq as f32 * 0.01,
        status: 0,
    }
}

fn wire(f: &Frame) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME_ENCODED];
    let n = codec::encode(f, &mut out).unwrap();
    out[..n].to_vec()
}

fn feed(rx: &mut Receiver, bytes: &[u8]) -> Vec<Frame> {
    let mut v = Vec::new();
    rx.push_slice(bytes, |f| v.push(f));
    v
}

#[test]
fn example_frame_matches_the_spec_bytes_exactly() {
    let bytes = wire(&Frame::Sample(EXAMPLE));
    assert_eq!(
        bytes, EXAMPLE_WIRE,
        "encoder output differs from LINK-FORMAT.md: {bytes:02X?}"
    );
    let mut rx: Receiver = Receiver::new();
    assert_eq!(feed(&mut rx, &EXAMPLE_WIRE), [Frame::Sample(EXAMPLE)]);
    // The spec file itself quotes the same bytes (keeps document and code in step).
    let spec = include_str!("../../LINK-FORMAT.md");
    let hex: Vec<String> = EXAMPLE_WIRE.iter().map(|b| format!("{b:02X}")).collect();
    assert!(
        spec.contains(&hex.join(" ")),
        "LINK-FORMAT.md does not quote the example bytes"
    );
}

#[test]
fn frame_size_bound_holds_for_the_largest_frames() {
    let cal = Calibration {
        divider: Divider {
            r_pulldown_ohm: f32::MAX,
            v_supply_v: f32::MAX,
        },
        curve: ForceCurve::Monotone {
            len: MAX_KNOTS as u8,
            conductance_us: core::array::from_fn(|i| 1.0e30 + i as f32 * 1.0e24),
            force_n: [f32::MAX; MAX_KNOTS],
        },
        usable_min_n: 0.0,
        usable_max_n: f32::MAX,
    };
    let big = [
        Frame::Config(Config {
            rate_hz: 3300,
            filter_cutoff_hz: f32::MAX,
            calibration: cal,
        }),
        Frame::Sample(ForceSample {
            seq: u32::MAX,
            timestamp_us: u64::MAX,
            raw_counts: i16::MIN,
            force_n: -f32::MAX,
            status: status::ALL,
        }),
        Frame::Hello(Hello {
            protocol_version: u16::MAX,
            firmware_version: u16::MAX,
            device_id: u32::MAX,
            rate_hz: u16::MAX,
        }),
        Frame::Error(ErrorReport {
            code: ErrorCode::TxDropped,
            detail: u32::MAX,
        }),
    ];
    for f in big {
        let b = wire(&f);
        assert!(
            b.len() <= MAX_FRAME_ENCODED,
            "{} > {MAX_FRAME_ENCODED}",
            b.len()
        );
        let mut rx: Receiver = Receiver::new();
        assert_eq!(feed(&mut rx, &b), [f]);
    }
    let mut small = [0u8; 8];
    assert!(matches!(
        codec::encode(&big[0], &mut small),
        Err(LinkError::BufferTooSmall { .. }) | Err(LinkError::Serialize)
    ));
}

#[test]
fn resynchronises_after_garbage_and_counts_it() {
    let mut rx: Receiver = Receiver::new();
    let mut bytes = vec![0x55u8; 500]; // longer than any frame: one overflow
    bytes.push(0);
    bytes.extend(wire(&Frame::Sample(sample(0))));
    bytes.extend([1, 2, 3, 0]); // short garbage: COBS-valid but too short
    bytes.extend(wire(&Frame::Sample(sample(1))));
    bytes.extend([0x07, 9, 9, 9, 9, 9, 9, 0]); // CRC garbage
    bytes.extend(wire(&Frame::Sample(sample(2))));
    let got = feed(&mut rx, &bytes);
    assert_eq!(got, [0, 1, 2].map(|s| Frame::Sample(sample(s))));
    let st = rx.stats();
    assert_eq!(
        (
            st.rejected_overflow,
            st.rejected_short,
            st.rejected_crc,
            st.missing_samples
        ),
        (1, 1, 1, 0)
    );
    assert_eq!(st.rejected(), 3);
}

#[test]
fn sequence_gaps_restarts_and_duplicates_are_counted() {
    let mut rx: Receiver = Receiver::new();
    let hello = Frame::Hello(Hello {
        protocol_version: 1,
        firmware_version: 0x0100,
        device_id: 7,
        rate_hz: 1000,
    });
    let mut bytes = wire(&hello);
    for s in [0u32, 1, 4, 4, 5] {
        bytes.extend(wire(&Frame::Sample(sample(s))));
    }
    bytes.extend(wire(&Frame::Sample(sample(2)))); // backwards without hello: reset
    bytes.extend(wire(&hello));
    bytes.extend(wire(&Frame::Sample(sample(3)))); // after hello numbering restarts at 0: 3 missing
    let got = feed(&mut rx, &bytes);
    assert_eq!(got.len(), 8);
    let st = rx.stats();
    assert_eq!(st.missing_samples, 2 + 3);
    assert_eq!(st.rejected_duplicate, 1);
    assert_eq!(st.restarts, 2);
}

#[test]
fn foreign_version_is_rejected_and_reported() {
    let mut out = [0u8; MAX_FRAME_ENCODED];
    let n = codec::encode_with_version(2, &Frame::Sample(sample(0)), &mut out).unwrap();
    let mut rx: Receiver = Receiver::new();
    assert_eq!(rx.push_slice(&out[..n], |_| {}), 0);
    assert_eq!(rx.stats().rejected_version, 1);
    assert_eq!(rx.peer_version(), Some(2));
}

#[test]
fn invalid_content_is_refused_both_ways() {
    let bad = Frame::Sample(ForceSample {
        force_n: f32::NAN,
        ..sample(0)
    });
    let mut out = [0u8; MAX_FRAME_ENCODED];
    assert_eq!(
        codec::encode(&bad, &mut out),
        Err(LinkError::Invalid("sample force is not finite"))
    );
    // Forge one with a valid CRC: the receiver must still refuse it.
    let mut body = vec![LINK_VERSION];
    let mut tmp = [0u8; MAX_FRAME_POSTCARD];
    body.extend_from_slice(postcard::to_slice(&bad, &mut tmp).unwrap());
    let crc = codec::CRC.checksum(&body);
    body.extend(crc.to_le_bytes());
    let mut enc = vec![0u8; body.len() + 4];
    let n = cobs::encode(&body, &mut enc);
    enc.truncate(n);
    enc.push(0);
    let mut rx: Receiver = Receiver::new();
    assert_eq!(rx.push_slice(&enc, |_| {}), 0);
    assert_eq!(rx.stats().rejected_invalid, 1);
}

proptest! {
    /// Random byte corruption, drops and insertions: whatever is delivered is exactly a frame
    /// that was sent, in order, and delivered + missing accounts for every sample from the first
    /// to the last delivered one.
    #[test]
    fn damaged_streams_never_deliver_a_corrupted_frame(
        edits in proptest::collection::vec((0usize..4000, 0u8..3, any::<u8>()), 0..60)
    ) {
        let sent: Vec<Frame> = (0..150).map(|s| Frame::Sample(sample(s))).collect();
        let mut bytes: Vec<u8> = sent.iter().flat_map(wire).collect();
        for (pos, kind, val) in edits {
            let p = pos % bytes.len();
            match kind {
                0 => bytes[p] ^= val.max(1),
                1 => { bytes.remove(p); }
                _ => bytes.insert(p, val),
            }
        }
        let mut rx: Receiver = Receiver::new();
        let got = feed(&mut rx, &bytes);
        let mut last = None;
        for f in &got {
            let Frame::Sample(s) = f else { panic!("unexpected frame {f:?}") };
            prop_assert_eq!(*f, sent[s.seq as usize]);
            if let Some(l) = last { prop_assert!(s.seq > l); }
            last = Some(s.seq);
        }
        if let (Some(Frame::Sample(a)), Some(Frame::Sample(b))) = (got.first(), got.last()) {
            prop_assert_eq!(rx.stats().samples + rx.stats().missing_samples, u64::from(b.seq - a.seq) + 1);
        }
    }
}
