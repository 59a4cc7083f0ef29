//! Bounded boxes.

/// A box `[low_i, high_i]` per dimension.
#[derive(Clone, Debug, PartialEq)]
pub struct BoxSpace {
    pub low: Vec<f32>,
    pub high: Vec<f32>,
}

/// A vector that does not belong to a space; names what the vector is and which entry fails.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SpaceError {
    #[error("{what} has {got} values, expected {expected}")]
    Dim { what: &'static str, expected: usize, got: usize },
    #[error("{what}[{index}] is not finite ({value})")]
    NonFinite { what: &'static str, index: usize, value: f32 },
    #[error("{what}[{index}] = {value} is outside its bounds [{low}, {high}]")]
    OutOfBounds { what: &'static str, index: usize, value: f32, low: f32, high: f32 },
    #[error("invalid space: {0}")]
    Invalid(String),
}

impl BoxSpace {
    pub fn new(low: Vec<f32>, high: Vec<f32>) -> Result<Self, SpaceError> {
        if low.len() != high.len() {
            return Err(SpaceError::Invalid(format!("{} lower bounds but {} upper bounds", low.len(), high.len())));
        }
        if let Some(i) = (0..low.len()).find(|&i| low[i].is_nan() || high[i].is_nan() || low[i] > high[i]) {
            return Err(SpaceError::Invalid(format!("bound {i}: low {} > high {}", low[i], high[i])));
        }
        Ok(Self { low, high })
    }

    /// The same bounds `[low, high]` in each of `dim` dimensions.
    pub fn uniform(dim: usize, low: f32, high: f32) -> Self {
        Self { low: vec![low; dim], high: vec![high; dim] }
    }

    pub fn dim(&self) -> usize {
        self.low.len()
    }

    /// Checks dimension, finiteness and bounds of `v`, naming it `what` in the error.
    pub fn check(&self, what: &'static str, v: &[f32]) -> Result<(), SpaceError> {
        self.check_finite(what, v)?;
        for (index, &value) in v.iter().enumerate() {
            let (low, high) = (self.low[index], self.high[index]);
            if value < low || value > high {
                return Err(SpaceError::OutOfBounds { what, index, value, low, high });
            }
        }
        Ok(())
    }

    /// Checks dimension and finiteness only (values outside the box are allowed, e.g. actions
    /// that the environment clips).
    pub fn check_finite(&self, what: &'static str, v: &[f32]) -> Result<(), SpaceError> {
        if v.len() != self.dim() {
            return Err(SpaceError::Dim { what, expected: self.dim(), got: v.len() });
        }
        match v.iter().position(|x| !x.is_finite()) {
            Some(index) => Err(SpaceError::NonFinite { what, index, value: v[index] }),
            None => Ok(()),
        }
    }

    /// Clips `v` into the box in place.
    pub fn clip(&self, v: &mut [f32]) {
        for ((x, lo), hi) in v.iter_mut().zip(&self.low).zip(&self.high) {
            *x = x.clamp(*lo, *hi);
        }
    }

    /// A point drawn uniformly from the box.
    pub fn sample<R: rand::Rng + ?Sized>(&self, rng: &mut R, out: &mut [f32]) {
        for ((x, lo), hi) in out.iter_mut().zip(&self.low).zip(&self.high) {
            *x = if lo == hi { *lo } else { rng.random_range(*lo..*hi) };
        }
    }
}
