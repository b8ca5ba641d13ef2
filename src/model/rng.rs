//! The simulator's own random numbers, so that a session is the same for a seed on every
//! platform and every version of every dependency (the `rand` crate does not promise stable
//! streams): xoshiro256** (Blackman and Vigna, 2018) seeded through SplitMix64, uniform deviates
//! from the top 53 bits, normal deviates by Box-Muller (one deviate from two uniforms, so every
//! draw consumes a fixed number of outputs).

use nalgebra::Vector3;

/// SplitMix64 (Steele, Lea and Flood, 2014): expands one 64-bit seed into the xoshiro state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator started at `seed`.
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// The next output.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// The independent random streams of a session: each purpose has its own, so that changing one
/// (e.g. switching the high-speed camera off) leaves the draws of the others unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    /// Launch states: real or random, which record, the random draws and their redraws.
    Launch,
    /// The gaps between shots.
    Schedule,
    /// The phases of the cameras' frame clocks.
    Clock,
    /// Everything per frame of the wide camera (dropout, noise, outliers, latency).
    WideCamera,
    /// Everything per frame of the high-speed camera (dropout, noise, outliers, spin, latency).
    HighSpeedCamera,
    /// The wide camera's frame intervals, when they are jittered.
    WideClockJitter,
    /// The high-speed camera's frame intervals, when they are jittered.
    HighSpeedClockJitter,
}

impl Stream {
    fn key(self) -> u64 {
        match self {
            Self::Launch => 1,
            Self::Schedule => 2,
            Self::Clock => 3,
            Self::WideCamera => 4,
            Self::HighSpeedCamera => 5,
            Self::WideClockJitter => 6,
            Self::HighSpeedClockJitter => 7,
        }
    }
}

/// xoshiro256**: a small, fast generator with a 2^256 - 1 period.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rng {
    s: [u64; 4],
}

impl Rng {
    /// A generator whose state is four outputs of SplitMix64 started at `seed`.
    pub fn new(seed: u64) -> Self {
        let mut mix = SplitMix64::new(seed);
        let mut s = [
            mix.next_u64(),
            mix.next_u64(),
            mix.next_u64(),
            mix.next_u64(),
        ];
        if s == [0; 4] {
            // The one state xoshiro cannot leave; SplitMix64 never produces it in practice.
            s[0] = 1;
        }
        Self::from_state(s)
    }

    /// The generator of one stream of the session seeded with `seed`.
    pub fn stream(seed: u64, stream: Stream) -> Self {
        let key = SplitMix64::new(stream.key()).next_u64();
        Self::new(SplitMix64::new(seed ^ key).next_u64())
    }

    /// A generator with the given raw state (not all zero).
    pub fn from_state(s: [u64; 4]) -> Self {
        Self { s }
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// A uniform deviate in [0, 1) with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A uniform deviate in [min, max).
    pub fn uniform_in(&mut self, min: f64, max: f64) -> f64 {
        min + (max - min) * self.uniform()
    }

    /// A uniform index in 0..n (0 when n is 0); Lemire's multiply-shift, bias below 2^-32 for
    /// the sizes used here.
    pub fn index(&mut self, n: usize) -> usize {
        ((u128::from(self.next_u64()) * n as u128) >> 64) as usize
    }

    /// True with probability `p`.
    pub fn bernoulli(&mut self, p: f64) -> bool {
        self.uniform() < p
    }

    /// A standard normal deviate (Box-Muller, cosine branch); consumes two outputs.
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform(); // (0, 1]: the logarithm is finite
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Three independent standard normal deviates.
    pub fn normal3(&mut self) -> Vector3<f64> {
        let x = self.normal();
        let y = self.normal();
        let z = self.normal();
        Vector3::new(x, y, z)
    }

    /// A direction uniform on the unit sphere.
    pub fn unit_vector(&mut self) -> Vector3<f64> {
        loop {
            let v = self.normal3();
            let n = v.norm();
            if n > 1e-9 {
                return v / n;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_matches_the_reference_outputs() {
        // splitmix64.c by Vigna, seeded with 0.
        let mut g = SplitMix64::new(0);
        assert_eq!(g.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(g.next_u64(), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(g.next_u64(), 0x06C4_5D18_8009_454F);
    }

    #[test]
    fn xoshiro256starstar_matches_the_reference_outputs() {
        // xoshiro256starstar.c by Blackman and Vigna, state {1, 2, 3, 4}.
        let mut g = Rng::from_state([1, 2, 3, 4]);
        let out: Vec<u64> = (0..6).map(|_| g.next_u64()).collect();
        assert_eq!(
            out,
            [
                11520,
                0,
                1509978240,
                1215971899390074240,
                1216172134540287360,
                607988272756665600
            ]
        );
    }

    #[test]
    fn streams_differ_and_repeat() {
        let a: Vec<u64> = {
            let mut g = Rng::stream(7, Stream::Launch);
            (0..4).map(|_| g.next_u64()).collect()
        };
        let b: Vec<u64> = {
            let mut g = Rng::stream(7, Stream::Launch);
            (0..4).map(|_| g.next_u64()).collect()
        };
        let c: Vec<u64> = {
            let mut g = Rng::stream(7, Stream::Clock);
            (0..4).map(|_| g.next_u64()).collect()
        };
        let d: Vec<u64> = {
            let mut g = Rng::stream(8, Stream::Launch);
            (0..4).map(|_| g.next_u64()).collect()
        };
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_ne!(a, d);
    }

    #[test]
    fn normal_deviates_have_unit_moments() {
        let mut g = Rng::new(42);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| g.normal()).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        let tail = xs.iter().filter(|x| x.abs() > 1.96).count() as f64 / n as f64;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.01, "variance {var}");
        assert!((tail - 0.05).abs() < 0.003, "two-sided 5 % tail {tail}");
    }

    #[test]
    fn uniform_and_index_cover_their_ranges() {
        let mut g = Rng::new(3);
        let mut counts = [0usize; 5];
        let mut lo = 1.0f64;
        let mut hi = 0.0f64;
        for _ in 0..50_000 {
            counts[g.index(5)] += 1;
            let u = g.uniform();
            lo = lo.min(u);
            hi = hi.max(u);
        }
        assert!((0.0..1e-3).contains(&lo) && (1.0 - 1e-3..1.0).contains(&hi));
        for c in counts {
            assert!((c as f64 / 10_000.0 - 1.0).abs() < 0.05, "{counts:?}");
        }
    }
}
