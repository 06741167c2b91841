//! The engine follows a time master (SPEC 9): SYNC / FOLLOW-UP frames on the time
//! identifier, written here byte by byte from SPEC 9.2, map the bridge's clock to the
//! master's; status page 7 (SPEC 5) reports it after each FOLLOW-UP.

use bridge::engine::{Bridge, BridgeConfig};
use can_wire::{Frame, FrameFormat, IdWindow, Kind, Status};
use embedded_can::{ExtendedId, Id, StandardId};

const Q: usize = 64;

fn config(window: IdWindow) -> BridgeConfig {
    BridgeConfig {
        encoding: can_wire::Encoding::PLAIN_MM,
        status_period_ms: 0,
        ..BridgeConfig::new(window.node(5).unwrap(), FrameFormat::Classic)
    }
}

fn std_id(raw: u16) -> Id {
    Id::Standard(StandardId::new(raw).unwrap())
}

/// SYNC: byte 0 = type 1 | seq << 4.
fn sync(id: Id, seq: u8) -> Frame {
    Frame::new(id, &[0x01 | seq << 4], false).unwrap()
}

/// FOLLOW-UP: byte 0 = type 2 | seq << 4, bytes 1..8 the time, 56 bits little-endian.
fn follow_up(id: Id, seq: u8, master_us: u64) -> Frame {
    let t = master_us.to_le_bytes();
    let mut b = vec![0x02 | seq << 4];
    b.extend_from_slice(&t[..7]);
    Frame::new(id, &b, false).unwrap()
}

fn pages(b: &mut Bridge<Q>) -> Vec<Status> {
    let status_id = b.config().ids.id(Kind::Status);
    std::iter::from_fn(|| b.pop_frame())
        .filter(|f| f.id() == status_id)
        .map(|f| Status::parse(f.data()).unwrap())
        .collect()
}

/// 2026-01-01 in Unix µs.
const T0: u64 = 1_767_225_600_000_000;

#[test]
fn follows_the_master_on_the_default_id() {
    let mut b = Bridge::<Q>::new(config(IdWindow::DEFAULT)).unwrap();
    let id = std_id(0x0FF);
    assert_eq!(b.to_master(1_000), None);
    // The bridge's clock is 2.5 s; the master sent the SYNC at T0.
    assert!(!b.on_can_frame_at(&sync(id, 9), 2_500_000));
    assert!(pages(&mut b).is_empty());
    assert!(!b.on_can_frame_at(&follow_up(id, 9, T0), 2_500_900));
    // Page 7: synced, no error yet, the FOLLOW-UP's reception (900 µs after the SYNC's)
    // in the master's clock, modulo 2^32.
    assert_eq!(
        pages(&mut b),
        vec![Status::TimeSync {
            synced: true,
            error_us: 0,
            master_time: ((T0 + 900) % (1 << 32)) as u32,
        }]
    );
    assert_eq!(b.to_master(2_500_000), Some(T0));
    assert_eq!(b.to_master(3_000_000), Some(T0 + 500_000));
    assert_eq!(b.time_sync().stats().samples, 1);
    // Held for 10 s, then gone.
    assert_eq!(b.to_master(12_500_000), Some(T0 + 10_000_000));
    assert_eq!(b.to_master(12_500_001), None);
}

#[test]
fn millisecond_entry_point_takes_time_frames_too() {
    let mut b = Bridge::<Q>::new(config(IdWindow::DEFAULT)).unwrap();
    let id = std_id(0x0FF);
    b.on_can_frame(&sync(id, 0), 7);
    b.on_can_frame(&follow_up(id, 0, T0), 8);
    assert_eq!(b.to_master(7_000), Some(T0));
}

#[test]
fn unpaired_follow_up_reports_not_synced_and_malformed_frames_are_counted() {
    let mut b = Bridge::<Q>::new(config(IdWindow::DEFAULT)).unwrap();
    let id = std_id(0x0FF);
    b.on_can_frame_at(&follow_up(id, 1, T0), 10);
    assert_eq!(
        pages(&mut b),
        vec![Status::TimeSync {
            synced: false,
            error_us: 0,
            master_time: 0
        }]
    );
    assert_eq!(b.time_sync().stats().orphans, 1);
    for bad in [&[][..], &[0x01, 0], &[0x03], &[0x02; 7]] {
        assert!(!b.on_can_frame_at(&Frame::new(id, bad, false).unwrap(), 20));
    }
    assert_eq!(b.time_sync().stats().malformed, 4);
    assert!(pages(&mut b).is_empty());
    assert_eq!(b.to_master(20), None);
}

#[test]
fn other_ids_are_not_time_frames_and_control_still_works() {
    let mut b = Bridge::<Q>::new(config(IdWindow::DEFAULT)).unwrap();
    // 0x0FE: not the time identifier.
    b.on_can_frame_at(&sync(std_id(0x0FE), 0), 1_000);
    b.on_can_frame_at(&follow_up(std_id(0x0FE), 0, T0), 2_000);
    assert_eq!(b.to_master(2_000), None);
    assert_eq!(b.time_sync().stats().syncs, 0);
    // A control frame to node 5 (0x105): reset counters, answered.
    assert!(b.on_can_frame_at(
        &Frame::new(std_id(0x105), &[0x04, 7], false).unwrap(),
        3_000
    ));
}

#[test]
fn configurable_id() {
    let mut b = Bridge::<Q>::new(config(IdWindow::DEFAULT)).unwrap();
    // Inside the window, or beyond 11 bits: refused.
    assert!(b.set_time_id(Some(0x100)).is_err());
    assert!(b.set_time_id(Some(0x17F)).is_err());
    assert!(b.set_time_id(Some(0x800)).is_err());
    b.set_time_id(Some(0x080)).unwrap();
    b.on_can_frame_at(&sync(std_id(0x0FF), 0), 1_000);
    b.on_can_frame_at(&follow_up(std_id(0x0FF), 0, T0), 1_100);
    assert_eq!(b.to_master(1_000), None);
    b.on_can_frame_at(&sync(std_id(0x080), 1), 1_000);
    b.on_can_frame_at(&follow_up(std_id(0x080), 1, T0), 1_100);
    assert_eq!(b.to_master(1_000), Some(T0));
    b.set_time_id(None).unwrap();
    assert_eq!(b.to_master(1_000), None);
    b.on_can_frame_at(&sync(std_id(0x080), 2), 2_000);
    assert_eq!(b.time_sync().stats().syncs, 1);
}

#[test]
fn extended_window_uses_an_extended_time_id_and_a_window_holding_0x0ff_has_none() {
    let window = IdWindow::extended(0x10_0000).unwrap();
    let mut b = Bridge::<Q>::new(config(window)).unwrap();
    let x = Id::Extended(ExtendedId::new(0x0FF).unwrap());
    b.on_can_frame_at(&sync(std_id(0x0FF), 0), 1_000);
    b.on_can_frame_at(&follow_up(std_id(0x0FF), 0, T0), 1_100);
    assert_eq!(b.to_master(1_000), None);
    b.on_can_frame_at(&sync(x, 1), 1_000);
    b.on_can_frame_at(&follow_up(x, 1, T0), 1_100);
    assert_eq!(b.to_master(1_000), Some(T0));

    let mut b = Bridge::<Q>::new(config(IdWindow::standard(0x0C0).unwrap())).unwrap();
    b.on_can_frame_at(&sync(std_id(0x0FF), 0), 1_000);
    assert_eq!(b.time_sync().stats().syncs, 0);
}
