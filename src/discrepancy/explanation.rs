//! How much of a gap the named effects explain: one verdict for the diagnosis of logs and of
//! recordings.

/// How much of the gap the named effects explain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Explanation {
    /// Nothing named, and the baseline's gap is what noise explains.
    NothingToExplain,
    /// Effects named, and what is left is what noise explains.
    Complete,
    /// Effects named, but the gap left is still above the noise: they are part of the answer.
    Partial,
    /// Nothing named, and the gap is above the noise.
    Unexplained,
}

impl Explanation {
    pub fn as_str(&self) -> &'static str {
        match self {
            Explanation::NothingToExplain => "nothing to explain",
            Explanation::Complete => "complete",
            Explanation::Partial => "partial",
            Explanation::Unexplained => "unexplained",
        }
    }
}
