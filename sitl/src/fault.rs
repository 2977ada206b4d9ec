//! Faults that tests and the command line can inject into a simulated bus.

/// A fault to inject, bus-wide or into one servo (see `SimHandle::inject`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// Flip bits in one byte of a reply, with this probability per reply (1.0 = every reply).
    CorruptReplies { probability: f64 },
    /// Send no reply at all, with this probability per reply; the servo still acts on the packet.
    DropReplies { probability: f64 },
    /// Every `every`th reply of the servo (the `every`th, the `2·every`th, …) starts `delay_us`
    /// later than its return delay says: a servo that answers after the host's allowance.
    LateReplies { delay_us: u32, every: u32 },
    /// The RS485 adapter echoes every byte the host transmits back to the host (always bus-wide).
    Echo,
    /// The rod is blocked: it cannot move and draws the stall current while force is on.
    Stall,
    /// An external load opposing the rod, in newtons: slower moves, more current, no move at all above the
    /// available thrust.
    ExternalLoad { newtons: f32 },
    /// The servo heats up by itself quickly (15 °C/s) until the fault is cleared.
    Overheat,
    /// Registers 0–1 report this model number instead of 7510h.
    WrongModel(u16),
    /// The servo is unplugged: silent, ignores everything; clearing it plugs the servo back in
    /// (power-on state from flash).
    Unplugged,
}

/// The kind of a [`Fault`], without its value (for `SimHandle::clear`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FaultKind {
    CorruptReplies,
    DropReplies,
    LateReplies,
    Echo,
    Stall,
    ExternalLoad,
    Overheat,
    WrongModel,
    Unplugged,
}

impl Fault {
    /// This fault's kind.
    pub fn kind(&self) -> FaultKind {
        match self {
            Fault::CorruptReplies { .. } => FaultKind::CorruptReplies,
            Fault::DropReplies { .. } => FaultKind::DropReplies,
            Fault::LateReplies { .. } => FaultKind::LateReplies,
            Fault::Echo => FaultKind::Echo,
            Fault::Stall => FaultKind::Stall,
            Fault::ExternalLoad { .. } => FaultKind::ExternalLoad,
            Fault::Overheat => FaultKind::Overheat,
            Fault::WrongModel(_) => FaultKind::WrongModel,
            Fault::Unplugged => FaultKind::Unplugged,
        }
    }
}

/// Reply faults of one servo or of the whole bus.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ReplyFaults {
    pub corrupt_probability: Option<f64>,
    pub drop_probability: Option<f64>,
    /// [`Fault::LateReplies`]: the delay, and every how many replies.
    pub late: Option<(std::time::Duration, u32)>,
}

/// A tiny deterministic random generator (xorshift64*), so that a seeded run replays exactly.
#[derive(Debug, Clone)]
pub struct XorShift64 {
    state: u64,
}

impl XorShift64 {
    /// A generator from `seed` (0 is replaced by a fixed non-zero constant).
    pub fn new(seed: u64) -> Self {
        XorShift64 {
            state: if seed == 0 {
                0x9E37_79B9_7F4A_7C15
            } else {
                seed
            },
        }
    }

    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.state;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.state = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in `[0, 1)`.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// `true` with probability `p` (clamped to 0…1; NaN counts as 0).
    pub fn chance(&mut self, p: f64) -> bool {
        if p.is_nan() || p <= 0.0 {
            return false;
        }
        p >= 1.0 || self.next_f64() < p
    }

    /// A value in `0..n` (0 when `n` ≤ 1).
    pub fn below(&mut self, n: usize) -> usize {
        if n <= 1 {
            return 0;
        }
        (self.next_u64() % n as u64) as usize
    }

    /// A non-zero byte (to XOR into a byte so that it surely changes).
    pub fn nonzero_byte(&mut self) -> u8 {
        (self.next_u64() % 255) as u8 + 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_gives_the_same_sequence() {
        let mut a = XorShift64::new(42);
        let mut b = XorShift64::new(42);
        for _ in 0..100 {
            assert_eq!(a.next_u64(), b.next_u64());
        }
    }

    #[test]
    fn chance_respects_its_bounds_and_rate() {
        let mut rng = XorShift64::new(7);
        assert!((0..1000).all(|_| rng.chance(1.0)));
        assert!((0..1000).all(|_| !rng.chance(0.0)));
        let hits = (0..10_000).filter(|_| rng.chance(0.3)).count();
        assert!(
            (2_700..3_300).contains(&hits),
            "{hits} hits of 10000 at p = 0.3"
        );
    }

    #[test]
    fn nonzero_bytes_are_never_zero() {
        let mut rng = XorShift64::new(1);
        assert!((0..10_000).all(|_| rng.nonzero_byte() != 0));
    }
}
