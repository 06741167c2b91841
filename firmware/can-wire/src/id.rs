//! Identifiers: `ID = window + node + 0x10 * kind` (SPEC section 1).

use embedded_can::{ExtendedId, Id, StandardId};

use crate::Error;

/// Number of identifiers one window spans (8 kinds × 16 nodes).
pub const WINDOW_SPAN: u32 = 0x80;
/// Number of bridges (nodes) one window holds.
pub const NODES: u8 = 16;
/// The default window (and base ID of node 0).
pub const DEFAULT_WINDOW: u16 = 0x100;

/// What a frame is, from its identifier. Lower value = higher priority.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Kind {
    /// Control request, host → bridge.
    Control = 0,
    /// Answer to a control request.
    ControlAnswer = 1,
    /// Status / heartbeat.
    Status = 2,
    /// Scan header A (sequence, timestamp, count, unit).
    HeaderA = 3,
    /// Scan header B (encoding, geometry).
    HeaderB = 4,
    /// Scan data (points).
    Data = 5,
    /// Scan trailer (counts, CRC).
    Trailer = 6,
    /// Scan abandoned.
    Abort = 7,
}

impl Kind {
    /// All kinds in priority order.
    pub const ALL: [Kind; 8] = [
        Kind::Control,
        Kind::ControlAnswer,
        Kind::Status,
        Kind::HeaderA,
        Kind::HeaderB,
        Kind::Data,
        Kind::Trailer,
        Kind::Abort,
    ];

    fn from_index(i: u32) -> Option<Kind> {
        Kind::ALL.get(usize::try_from(i).ok()?).copied()
    }
}

/// A window of 128 identifiers shared by up to 16 bridges, 11-bit or 29-bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IdWindow {
    base: u32,
    extended: bool,
}

impl IdWindow {
    /// An 11-bit window starting at `base` (`base + 0x7F <= 0x7FF`).
    pub const fn standard(base: u16) -> Result<IdWindow, Error> {
        // A u16 plus 0x7F cannot wrap a u32.
        if (base as u32).wrapping_add(WINDOW_SPAN - 1) > 0x7FF {
            return Err(Error::BadIdWindow);
        }
        Ok(IdWindow {
            base: base as u32,
            extended: false,
        })
    }

    /// A 29-bit window starting at `base` (`base + 0x7F <= 0x1FFF_FFFF`).
    pub const fn extended(base: u32) -> Result<IdWindow, Error> {
        if base > 0x1FFF_FFFF - (WINDOW_SPAN - 1) {
            return Err(Error::BadIdWindow);
        }
        Ok(IdWindow {
            base,
            extended: true,
        })
    }

    /// The default window: 11-bit, base 0x100.
    pub const DEFAULT: IdWindow = IdWindow {
        base: DEFAULT_WINDOW as u32,
        extended: false,
    };

    /// First identifier of the window.
    pub const fn base(&self) -> u32 {
        self.base
    }

    /// Whether the window uses 29-bit identifiers.
    pub const fn is_extended(&self) -> bool {
        self.extended
    }

    /// The identifiers of bridge `node` (0..16).
    pub fn node(&self, node: u8) -> Result<NodeIds, Error> {
        if node >= NODES {
            return Err(Error::BadIdWindow);
        }
        Ok(NodeIds {
            window: *self,
            node,
        })
    }

    /// Which bridge and kind an identifier belongs to, or `None` if it is not ours.
    pub fn classify(&self, id: Id) -> Option<(u8, Kind)> {
        let raw = match (id, self.extended) {
            (Id::Standard(s), false) => u32::from(s.as_raw()),
            (Id::Extended(e), true) => e.as_raw(),
            _ => return None,
        };
        let offset = raw.checked_sub(self.base)?;
        if offset >= WINDOW_SPAN {
            return None;
        }
        let kind = Kind::from_index(offset >> 4)?;
        Some(((offset & 0xF) as u8, kind))
    }
}

impl Default for IdWindow {
    fn default() -> Self {
        IdWindow::DEFAULT
    }
}

/// The identifiers of one bridge: its base is `window + node`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NodeIds {
    window: IdWindow,
    node: u8,
}

impl NodeIds {
    /// The bridge's node number (0..16) inside its window.
    pub const fn node(&self) -> u8 {
        self.node
    }

    /// The window this bridge lives in.
    pub const fn window(&self) -> IdWindow {
        self.window
    }

    /// The bridge's base ID (its control frame ID).
    pub const fn base(&self) -> u32 {
        // The window ends at 0x1FFF_FFFF at most: adding a node number cannot wrap.
        self.window.base.wrapping_add(self.node as u32)
    }

    /// The identifier of frames of `kind` from or to this bridge.
    pub fn id(&self, kind: Kind) -> Id {
        // At most 0x1FFF_FFFF + 0xFF + 0x10 * 7: no wrap.
        let raw = self.base().wrapping_add(0x10u32.wrapping_mul(kind as u32));
        // The window constructors guarantee `raw` fits; fall back to the base if not.
        if self.window.extended {
            Id::Extended(ExtendedId::new(raw).unwrap_or(ExtendedId::ZERO))
        } else {
            let raw = u16::try_from(raw).unwrap_or(0);
            Id::Standard(StandardId::new(raw).unwrap_or(StandardId::ZERO))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn std_id(raw: u16) -> Id {
        Id::Standard(StandardId::new(raw).unwrap())
    }

    #[test]
    fn default_ids() {
        let n = IdWindow::DEFAULT.node(0).unwrap();
        let ids: Vec<Id> = Kind::ALL.iter().map(|k| n.id(*k)).collect();
        let want: Vec<Id> = [0x100, 0x110, 0x120, 0x130, 0x140, 0x150, 0x160, 0x170]
            .iter()
            .map(|r| std_id(*r))
            .collect();
        assert_eq!(ids, want);
        let n3 = IdWindow::DEFAULT.node(3).unwrap();
        assert_eq!(n3.id(Kind::Data), std_id(0x153));
        assert_eq!(n3.base(), 0x103);
    }

    #[test]
    fn classify_round_trip() {
        let w = IdWindow::standard(0x200).unwrap();
        for node in 0..NODES {
            for kind in Kind::ALL {
                let id = w.node(node).unwrap().id(kind);
                assert_eq!(w.classify(id), Some((node, kind)));
            }
        }
        assert_eq!(w.classify(std_id(0x1FF)), None);
        assert_eq!(w.classify(std_id(0x280)), None);
        let ext = Id::Extended(ExtendedId::new(0x200).unwrap());
        assert_eq!(w.classify(ext), None);
    }

    #[test]
    fn priority_order_across_nodes() {
        let w = IdWindow::DEFAULT;
        // Every control frame beats every status frame beats every scan frame.
        let worst_control = w.node(15).unwrap().id(Kind::Control);
        let best_status = w.node(0).unwrap().id(Kind::Status);
        let best_scan = w.node(0).unwrap().id(Kind::HeaderA);
        let worst_status = w.node(15).unwrap().id(Kind::Status);
        assert!(worst_control < best_status);
        assert!(worst_status < best_scan);
    }

    #[test]
    fn window_limits() {
        assert!(IdWindow::standard(0x780).is_ok());
        assert_eq!(IdWindow::standard(0x781), Err(Error::BadIdWindow));
        assert!(IdWindow::extended(0x1FFF_FF80).is_ok());
        assert_eq!(IdWindow::extended(0x1FFF_FF81), Err(Error::BadIdWindow));
        assert_eq!(IdWindow::DEFAULT.node(16), Err(Error::BadIdWindow));
        let w = IdWindow::extended(0x1FFF_FF80).unwrap();
        let id = w.node(15).unwrap().id(Kind::Abort);
        assert_eq!(id, Id::Extended(ExtendedId::new(0x1FFF_FFFF).unwrap()));
        assert_eq!(w.classify(id), Some((15, Kind::Abort)));
    }
}
