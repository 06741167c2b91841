//! A CAN or CAN FD data frame with up to 64 bytes, and the CAN FD length rules.

use embedded_can::Id;

use crate::Error;

/// Largest CAN FD payload.
pub const MAX_LEN: usize = 64;
/// Largest classic CAN payload.
pub const CLASSIC_LEN: usize = 8;
/// The payload lengths a CAN FD frame can have above 8 bytes.
pub const FD_LENGTHS: [u8; 7] = [12, 16, 20, 24, 32, 48, 64];

/// The smallest valid frame length that holds `len` bytes (`len` itself up to 8, else the
/// next CAN FD length), or `None` above 64.
pub const fn padded_len(len: usize) -> Option<usize> {
    if len <= CLASSIC_LEN {
        return Some(len);
    }
    let mut rest: &[u8] = &FD_LENGTHS;
    while let [first, tail @ ..] = rest {
        if *first as usize >= len {
            return Some(*first as usize);
        }
        rest = tail;
    }
    None
}

/// Whether `len` is a length a (classic or FD) frame can have.
pub const fn is_valid_len(len: usize) -> bool {
    matches!(padded_len(len), Some(p) if p == len)
}

/// A data frame (no remote frames: the protocol does not use them).
///
/// The payload comes first and word-aligned (`repr(C)`): a frame moves by value (out of
/// the encoder, into and out of queues), and on a 32-bit MCU a payload at an odd offset
/// (where the default layout put it) is copied byte by byte.
#[derive(Clone, Copy, PartialEq, Eq)]
#[repr(C, align(4))]
pub struct Frame {
    data: [u8; MAX_LEN],
    id: Id,
    shape: Shape,
}

/// The length and format of a classic frame ([`Frame::classic_shape`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClassicShape(Shape);

/// A frame's length (low byte) and format (bit 8: CAN FD) in one 16-bit value, so that
/// a run of classic data frames writes both with one store of a value made once
/// ([`Frame::set_classic_as`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Shape(u16);

impl Shape {
    /// `len` bytes (at most 64), CAN FD or not.
    #[inline(always)]
    const fn new(len: u8, fd: bool) -> Shape {
        Shape(len as u16 | (fd as u16) << 8)
    }

    /// The length, bytes.
    #[inline(always)]
    const fn len(self) -> u8 {
        self.0 as u8
    }

    /// Whether the frame is a CAN FD frame.
    #[inline(always)]
    const fn fd(self) -> bool {
        // Bit 8 alone (`new` sets no other above the length): one bit-field extract.
        self.0 & 0x100 != 0
    }
}

impl Frame {
    /// A frame with `data`; `fd` selects CAN FD. Fails if `data` is too long for the format
    /// or (CAN FD) not a valid FD length.
    pub fn new(id: Id, data: &[u8], fd: bool) -> Result<Frame, Error> {
        let len = data.len();
        let ok = if fd {
            is_valid_len(len)
        } else {
            len <= CLASSIC_LEN
        };
        if !ok {
            return Err(Error::FrameTooLong);
        }
        let mut buf = [0u8; MAX_LEN];
        buf.get_mut(..len)
            .ok_or(Error::FrameTooLong)?
            .copy_from_slice(data);
        Ok(Frame {
            id,
            data: buf,
            shape: Shape::new(len as u8, fd),
        })
    }

    /// Makes this frame what [`Frame::new`] would return for the same arguments, in
    /// place (no frame moves by value); on error the frame is left as it was.
    #[inline]
    pub fn set(&mut self, id: Id, data: &[u8], fd: bool) -> Result<(), Error> {
        let len = data.len();
        let ok = if fd {
            is_valid_len(len)
        } else {
            len <= CLASSIC_LEN
        };
        if !ok {
            return Err(Error::FrameTooLong);
        }
        // The bytes past `len` are zero in every frame: only the old payload's bytes
        // past the new one are cleared (none when the slot is fresh).
        if usize::from(self.shape.len()) > len {
            if let Some(stale) = self.data.get_mut(len..usize::from(self.shape.len())) {
                stale.fill(0);
            }
        }
        // Word by word: `copy_from_slice` of a run-time length is a `memcpy` call that
        // copies short payloads byte by byte (every FD length is whole words).
        // A classic data frame (the most frequent) as two words, a full 64-byte FD frame
        // as a copy of a length known at compile time; others with a memcpy.
        match (
            self.data.first_chunk_mut::<CLASSIC_LEN>(),
            <&[u8; CLASSIC_LEN]>::try_from(data),
        ) {
            (Some(head), Ok(eight)) => *head = *eight,
            _ => {
                if let Ok(all) = <&[u8; MAX_LEN]>::try_from(data) {
                    self.data = *all;
                } else if let Some(head) = self.data.get_mut(..len) {
                    head.copy_from_slice(data);
                }
            }
        }
        self.id = id;
        self.shape = Shape::new(len as u8, fd);
        Ok(())
    }

    /// Makes this a classic frame of the first `len` (at most 8) of `data`, whose bytes
    /// past `len` must be zero: [`Frame::set`] for a payload built in a 64-bit word. A
    /// longer `len` is cut to 8. Any frame may be set so (an older CAN FD frame's bytes
    /// past the 8th are cleared).
    #[inline]
    pub fn set_classic(&mut self, id: Id, data: [u8; CLASSIC_LEN], len: usize) {
        self.clear_fd_bytes();
        self.set_classic_as(id, data, Frame::classic_shape(len));
    }

    /// Zeroes the payload bytes past the 8th (a CAN FD frame's, none for a classic
    /// frame), keeping the rest: for a slot whose frame has left, so that it holds no
    /// byte past a classic frame's, as [`Frame::set_classic_as`] wants.
    #[inline]
    pub fn clear_fd_bytes(&mut self) {
        if usize::from(self.shape.len()) > CLASSIC_LEN {
            self.clear_past_classic();
        }
    }

    /// The length and format of a classic frame of `len` bytes (at most 8; a longer
    /// `len` is cut to 8), made once for [`Frame::set_classic_as`].
    #[inline]
    pub fn classic_shape(len: usize) -> ClassicShape {
        ClassicShape(Shape::new(len.min(CLASSIC_LEN) as u8, false))
    }

    /// [`Frame::set_classic`] with the length and format made beforehand
    /// ([`Frame::classic_shape`]) over a frame with no byte past the 8th (a classic
    /// frame, a default one, or one whose [`Frame::clear_fd_bytes`] ran: the data slots
    /// a [`crate::encoder::FrameSink`] hands out): a run of frames of one length writes
    /// each frame's payload word, identifier and shape, and nothing else. Over a CAN FD
    /// frame the payload and length are still this frame's, but the older bytes past
    /// the 8th stay in the slot (and the frame compares unequal to [`Frame::new`]'s).
    #[inline(always)]
    pub fn set_classic_as(&mut self, id: Id, data: [u8; CLASSIC_LEN], shape: ClassicShape) {
        if let Some(head) = self.data.first_chunk_mut::<CLASSIC_LEN>() {
            *head = data;
        }
        self.id = id;
        self.shape = shape.0;
    }

    /// Zeroes the payload bytes past a classic frame's 8 that a CAN FD frame holds
    /// ([`Frame::clear_fd_bytes`]: rare, out of line).
    #[cold]
    #[inline(never)]
    fn clear_past_classic(&mut self) {
        if let Some(stale) = self
            .data
            .get_mut(CLASSIC_LEN..usize::from(self.shape.len()))
        {
            stale.fill(0);
        }
    }

    /// The identifier.
    #[inline]
    pub fn id(&self) -> Id {
        self.id
    }

    /// The payload.
    #[inline(always)]
    pub fn data(&self) -> &[u8] {
        self.data
            .get(..usize::from(self.shape.len()))
            .unwrap_or(&[])
    }

    /// The data length, bytes.
    #[inline]
    pub fn len(&self) -> usize {
        usize::from(self.shape.len())
    }

    /// Whether the frame carries no data.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.shape.len() == 0
    }

    /// Whether this is a CAN FD frame.
    #[inline]
    pub fn is_fd(&self) -> bool {
        self.shape.fd()
    }
}

impl Default for Frame {
    /// A classic frame with standard id 0 and no data: a slot to [`Frame::set`].
    fn default() -> Self {
        Frame {
            data: [0; MAX_LEN],
            id: Id::Standard(embedded_can::StandardId::ZERO),
            shape: Shape::new(0, false),
        }
    }
}

impl core::fmt::Debug for Frame {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Frame")
            .field("id", &self.id)
            .field("data", &self.data())
            .field("fd", &self.shape.fd())
            .finish()
    }
}

impl embedded_can::Frame for Frame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        Frame::new(id.into(), data, data.len() > CLASSIC_LEN).ok()
    }

    fn new_remote(_id: impl Into<Id>, _dlc: usize) -> Option<Self> {
        None
    }

    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        false
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        usize::from(self.shape.len())
    }

    fn data(&self) -> &[u8] {
        Frame::data(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::StandardId;

    fn id() -> Id {
        Id::Standard(StandardId::new(0x150).unwrap())
    }

    #[test]
    fn set_in_place_equals_new_and_an_error_changes_nothing() {
        let mut f = Frame::new(id(), &[9; 12], true).unwrap();
        f.set(id(), &[1, 2, 3], false).unwrap();
        assert_eq!(f, Frame::new(id(), &[1, 2, 3], false).unwrap());
        assert_eq!(f.data(), &[1, 2, 3]);
        assert!(!f.is_fd());
        let before = f;
        assert_eq!(f.set(id(), &[0; 9], false), Err(Error::FrameTooLong));
        assert_eq!(f.set(id(), &[0; 13], true), Err(Error::FrameTooLong));
        assert_eq!(f, before);
        assert_eq!(
            Frame::default(),
            Frame::new(Id::Standard(StandardId::ZERO), &[], false).unwrap()
        );
    }

    /// A CAN FD frame's slot cleared past the 8th byte, then set as a classic frame
    /// with plain stores, is the classic frame `new` makes (every byte, by `==`); so is
    /// `set_classic` over an uncleared FD frame. Without the clearing the older bytes
    /// would stay (hand-built expectations, not the code's own output).
    #[test]
    fn classic_over_a_cleared_fd_slot_equals_new() {
        let payload = [1, 2, 3, 4, 5, 6, 7, 8];
        let want = Frame::new(id(), &payload, false).unwrap();
        for fd_len in [12, 16, 64] {
            let mut slot = Frame::new(id(), &[0xEE; 64][..fd_len], true).unwrap();
            slot.clear_fd_bytes();
            // The first 8 bytes are kept, the rest is zero, the shape is the FD frame's.
            assert_eq!(slot.len(), fd_len);
            assert!(slot.is_fd());
            let mut bytes = [0u8; 64];
            bytes[..8].fill(0xEE);
            assert_eq!(slot.data(), &bytes[..fd_len]);
            slot.set_classic_as(id(), payload, Frame::classic_shape(8));
            assert_eq!(slot, want);
            assert_eq!(slot.data(), &payload);
            let mut slot = Frame::new(id(), &[0xEE; 64][..fd_len], true).unwrap();
            slot.set_classic(id(), [9, 9, 9, 0, 0, 0, 0, 0], 3);
            assert_eq!(slot, Frame::new(id(), &[9, 9, 9], false).unwrap());
        }
        // A classic frame (edge: 8 bytes, and 0) loses nothing to the clearing.
        let mut f = want;
        f.clear_fd_bytes();
        assert_eq!(f, want);
        let mut e = Frame::default();
        e.clear_fd_bytes();
        assert_eq!(e, Frame::default());
        // Uncleared, the FD frame's byte 8 onwards would stay: the frames differ.
        let mut raw = Frame::new(id(), &[0xEE; 12], true).unwrap();
        raw.set_classic_as(id(), payload, Frame::classic_shape(8));
        assert_eq!(raw.data(), &payload);
        assert_ne!(raw, want);
    }

    #[test]
    fn lengths() {
        assert_eq!(padded_len(0), Some(0));
        assert_eq!(padded_len(8), Some(8));
        assert_eq!(padded_len(9), Some(12));
        assert_eq!(padded_len(33), Some(48));
        assert_eq!(padded_len(64), Some(64));
        assert_eq!(padded_len(65), None);
        assert!(is_valid_len(20));
        assert!(!is_valid_len(21));
    }

    #[test]
    fn new_checks_format() {
        assert_eq!(Frame::new(id(), &[0; 9], false), Err(Error::FrameTooLong));
        assert_eq!(Frame::new(id(), &[0; 13], true), Err(Error::FrameTooLong));
        assert_eq!(Frame::new(id(), &[0; 65], true), Err(Error::FrameTooLong));
        let f = Frame::new(id(), &[1, 2, 3], false).unwrap();
        assert_eq!(f.data(), &[1, 2, 3]);
        assert!(!f.is_fd());
        let g: Frame = embedded_can::Frame::new(id(), &[0; 12]).unwrap();
        assert!(g.is_fd());
        assert_eq!(embedded_can::Frame::dlc(&g), 12);
    }
}
