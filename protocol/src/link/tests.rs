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

/// The wire bytes of `sent` with `edits` applied in turn: `(position, kind, value)` flips the
/// bits of `value` (kind 0; at least one bit), removes the byte (kind 1) or inserts `value`
/// (otherwise) at `position` modulo the length.
fn damaged(sent: &[Frame], edits: Vec<(usize, u8, u8)>) -> Vec<u8> {
    let mut bytes: Vec<u8> = sent.iter().flat_map(wire).collect();
    for (pos, kind, val) in edits {
        let p = pos % bytes.len();
        match kind {
            0 => bytes[p] ^= val.max(1),
            1 => {
                bytes.remove(p);
            }
            _ => bytes.insert(p, val),
        }
    }
    bytes
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
        if let Frame::Hello(h) = f {
            // The largest hello claims version 65535 inside a version-1 frame: refused.
            let got: Vec<_> = b.iter().filter_map(|&x| rx.push(x)).collect();
            assert_eq!(
                got,
                [Err(Rejection::HelloVersionMismatch {
                    frame_version: LINK_VERSION,
                    hello_version: h.protocol_version
                })]
            );
            let ok = Frame::Hello(Hello {
                protocol_version: u16::from(LINK_VERSION),
                ..h
            });
            assert_eq!(feed(&mut rx, &wire(&ok)), [ok]);
        } else {
            assert_eq!(feed(&mut rx, &b), [f]);
        }
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

fn samples(seqs: &[u32]) -> Vec<u8> {
    seqs.iter()
        .flat_map(|&s| wire(&Frame::Sample(sample(s))))
        .collect()
}

fn hello(protocol_version: u16) -> Frame {
    Frame::Hello(Hello {
        protocol_version,
        firmware_version: 0x0100,
        device_id: 7,
        rate_hz: 1000,
    })
}

#[test]
fn sequence_wraps_from_u32_max_to_zero_seamlessly() {
    const M: u32 = u32::MAX;
    // In order across the wrap: nothing missing, no restart, no jump.
    let mut rx: Receiver = Receiver::new();
    let seqs = [M - 2, M - 1, M, 0, 1, 2];
    assert_eq!(feed(&mut rx, &samples(&seqs)).len(), seqs.len());
    let st = *rx.stats();
    assert_eq!(
        (
            st.missing_samples,
            st.restarts,
            st.seq_backwards,
            st.seq_jumps
        ),
        (0, 0, 0, 0),
        "{st:?}"
    );
    assert_eq!(rx.last_seq(), Some(2));
    // Gaps that straddle the wrap count exactly: M−1 → 1 skips M and 0; 1 → 5 skips 3 more;
    // and tracking goes on after the wrap (the old code stopped at u32::MAX).
    let mut rx: Receiver = Receiver::new();
    feed(&mut rx, &samples(&[M - 1, 1, 5, 6]));
    let st = *rx.stats();
    assert_eq!(
        (st.samples, st.missing_samples, st.restarts, st.seq_jumps),
        (4, 2 + 3, 0, 0),
        "{st:?}"
    );
    // A repeat of u32::MAX right after it is a duplicate, not a 4-billion gap.
    let mut rx: Receiver = Receiver::new();
    feed(&mut rx, &samples(&[M, M, 0]));
    let st = *rx.stats();
    assert_eq!(
        (st.samples, st.rejected_duplicate, st.missing_samples),
        (2, 1, 0),
        "{st:?}"
    );
}

#[test]
fn forged_far_future_seq_is_a_counted_jump_not_billions_missing() {
    let mut rx: Receiver = Receiver::new();
    let mut bytes = samples(&(0..100).collect::<Vec<_>>());
    bytes.extend(samples(&[4_000_000_000])); // one forged frame with a valid CRC
    bytes.extend(samples(&[100, 101, 105]));
    let got = feed(&mut rx, &bytes);
    assert_eq!(got.len(), 104);
    let st = *rx.stats();
    // The forged number is a jump (resynchronised, nothing missing); the genuine stream that
    // follows goes backwards from it (a restart); 101 → 105 is an ordinary gap of 3.
    assert_eq!(st.seq_jumps, 1, "{st:?}");
    assert_eq!(st.seq_backwards, 1, "{st:?}");
    assert_eq!(st.restarts, 1, "{st:?}");
    assert_eq!(st.missing_samples, 3, "{st:?}");
    assert_eq!(st.rejected(), 0);

    // The window edge: a step of exactly SEQ_WINDOW skips SEQ_WINDOW numbers (still counted);
    // one more is a jump. Also across the wrap.
    for start in [0u32, u32::MAX - 10] {
        let mut rx: Receiver = Receiver::new();
        let a = start.wrapping_add(1 + SEQ_WINDOW);
        let b = a.wrapping_add(1 + SEQ_WINDOW + 1);
        feed(&mut rx, &samples(&[start, a, b]));
        let st = *rx.stats();
        assert_eq!(
            (st.missing_samples, st.seq_jumps, st.restarts),
            (u64::from(SEQ_WINDOW), 1, 0),
            "start {start}: {st:?}"
        );
    }
    // The window covers several seconds at the highest configurable rate.
    const { assert!(SEQ_WINDOW >= 3 * 3300) };
}

#[test]
fn duplicate_and_backwards_frames_are_counted_as_such() {
    let mut rx: Receiver = Receiver::new();
    let mut bytes = wire(&hello(1));
    // 11 repeated: duplicate (rejected). 5 after 12: backwards (probe reset without a hello):
    // delivered, counted, tracking continues from 5. Then 0 … 2 after 6: backwards again.
    bytes.extend(samples(&[10, 11, 11, 12, 5, 6, 0, 1, 2]));
    let got: Vec<_> = bytes.iter().filter_map(|&b| rx.push(b)).collect();
    assert_eq!(got.len(), 10);
    assert_eq!(got[3], Err(Rejection::Duplicate { seq: 11 }));
    assert_eq!(
        Rejection::Duplicate { seq: 11 }.to_string(),
        "duplicate sample sequence number 11"
    );
    let st = *rx.stats();
    assert_eq!(st.samples, 8);
    assert_eq!(st.rejected_duplicate, 1);
    assert_eq!(st.rejected(), 1);
    assert_eq!(st.seq_backwards, 2);
    assert_eq!(st.restarts, 2);
    // Only the hello-relative gap (0 → 10) is missing; backwards steps add nothing.
    assert_eq!(st.missing_samples, 10);
    assert_eq!(st.seq_jumps, 0);

    // Backwards across the wrap: after 0, 1, 2 comes u32::MAX − 1 (the old unsigned
    // subtraction counted ~4.29e9 missing here).
    let mut rx: Receiver = Receiver::new();
    feed(&mut rx, &samples(&[0, 1, 2, u32::MAX - 1]));
    let st = *rx.stats();
    assert_eq!(
        (
            st.missing_samples,
            st.seq_backwards,
            st.restarts,
            st.seq_jumps
        ),
        (0, 1, 1, 0),
        "{st:?}"
    );
}

#[test]
fn hello_claiming_another_version_inside_a_v1_frame_is_refused() {
    let mut rx: Receiver = Receiver::new();
    let mut bytes = wire(&hello(1));
    bytes.extend(samples(&[0, 1]));
    bytes.extend(wire(&hello(2))); // intact v1 frame (CRC fine) whose hello says version 2
    bytes.extend(samples(&[2]));
    let got: Vec<_> = bytes.iter().filter_map(|&b| rx.push(b)).collect();
    let bad = Rejection::HelloVersionMismatch {
        frame_version: 1,
        hello_version: 2,
    };
    assert_eq!(got[3], Err(bad));
    assert_eq!(
        bad.to_string(),
        "hello claims protocol version 2 inside a version-1 frame"
    );
    let st = *rx.stats();
    assert_eq!(st.rejected_hello_version, 1);
    assert_eq!(st.rejected_version, 0);
    assert_eq!(st.rejected(), 1);
    // The refused hello did not restart the sequence: 2 follows 1 with nothing missing.
    assert_eq!((st.restarts, st.missing_samples, st.samples), (0, 0, 3));
    assert_eq!(rx.peer_version(), None);
    // A consistent hello still restarts it.
    feed(&mut rx, &wire(&hello(1)));
    assert_eq!(rx.stats().restarts, 1);
}

#[test]
fn encoding_into_a_full_heapless_buffer_is_a_typed_error() {
    let f = Frame::Sample(EXAMPLE);
    // Too small for one frame: typed error, buffer untouched.
    let mut tiny = heapless::Vec::<u8, 8>::new();
    assert_eq!(
        codec::encode_into(&f, &mut tiny),
        Err(LinkError::BufferTooSmall { needed: 21, got: 8 })
    );
    assert!(tiny.is_empty());
    // Room for one frame but not two: the second is refused, the first stays intact.
    let mut buf = heapless::Vec::<u8, 40>::new();
    assert_eq!(codec::encode_into(&f, &mut buf), Ok(21));
    assert_eq!(
        codec::encode_into(&f, &mut buf),
        Err(LinkError::BufferTooSmall {
            needed: 21,
            got: 19
        })
    );
    assert_eq!(buf[..], EXAMPLE_WIRE);
    // Exactly two fit; a buffer of one frame's bound always holds one frame.
    let mut two = heapless::Vec::<u8, 42>::new();
    codec::encode_into(&f, &mut two).unwrap();
    codec::encode_into(&f, &mut two).unwrap();
    assert!(two.is_full());
    assert_eq!(two[21..], EXAMPLE_WIRE);
    let mut one = heapless::Vec::<u8, MAX_FRAME_ENCODED>::new();
    let n = codec::encode_into_with_version(2, &f, &mut one).unwrap();
    assert_eq!((n, one[1]), (21, 2));
}

#[test]
fn a_full_receiver_buffer_is_an_overflow_rejection_not_a_panic() {
    // A receiver whose buffer just holds the 20 non-zero bytes of the example frame.
    let mut rx = Receiver::<20>::new();
    let mut out = Vec::new();
    for &b in [0x55u8; 300].iter().chain(&[0]) {
        out.extend(rx.push(b));
    }
    assert_eq!(out, [Err(Rejection::Overflow)]);
    assert_eq!(rx.stats().rejected_overflow, 1);
    assert_eq!(rx.stats().bytes_discarded, 300);
    // Back in sync at the delimiter; a frame that fills the buffer exactly is delivered.
    let got: Vec<_> = EXAMPLE_WIRE.iter().filter_map(|&b| rx.push(b)).collect();
    assert_eq!(got, [Ok(Frame::Sample(EXAMPLE))]);
    // One byte more than the buffer holds is an overflow; a partial frame dropped on reopen
    // counts its bytes.
    let mut long = vec![0x01; 21];
    long.push(0);
    let got: Vec<_> = long.iter().filter_map(|&b| rx.push(b)).collect();
    assert_eq!(got, [Err(Rejection::Overflow)]);
    for &b in &EXAMPLE_WIRE[..10] {
        assert_eq!(rx.push(b), None);
    }
    rx.reset_partial();
    assert_eq!(rx.stats().bytes_discarded, 300 + 21 + 10);
    assert_eq!(rx.stats().rejected(), 2);
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
        let mut rx: Receiver = Receiver::new();
        let got = feed(&mut rx, &damaged(&sent, edits));
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

    /// The same damage on a stream whose numbers wrap from u32::MAX to 0 in the middle: the
    /// accounting is exact across the wrap (serial-number arithmetic), with no restart or jump.
    #[test]
    fn damaged_streams_across_the_seq_wrap_account_for_every_sample(
        edits in proptest::collection::vec((0usize..4000, 0u8..3, any::<u8>()), 0..60)
    ) {
        let start = u32::MAX - 74;
        let sent: Vec<Frame> = (0..150u32).map(|k| Frame::Sample(sample(start.wrapping_add(k)))).collect();
        let mut rx: Receiver = Receiver::new();
        let got = feed(&mut rx, &damaged(&sent, edits));
        let mut last = None;
        for f in &got {
            let Frame::Sample(s) = f else { panic!("unexpected frame {f:?}") };
            let k = s.seq.wrapping_sub(start);
            prop_assert_eq!(*f, sent[k as usize]);
            if let Some(l) = last { prop_assert!(k > l); }
            last = Some(k);
        }
        if let (Some(Frame::Sample(a)), Some(Frame::Sample(b))) = (got.first(), got.last()) {
            let span = b.seq.wrapping_sub(a.seq);
            prop_assert_eq!(rx.stats().samples + rx.stats().missing_samples, u64::from(span) + 1);
        }
        let st = rx.stats();
        prop_assert_eq!((st.restarts, st.seq_backwards, st.seq_jumps), (0, 0, 0));
    }
}
