//! Which of an answer's re-solves a sequence of answers (a tracking run's
//! frames) makes anew: all of them, or a few in turn while the others are
//! carried from the answer that last made them, each its offset from that
//! answer put on the new one ([`Refresh::every`]). A column is the
//! answer's response to one unknown; over a few frames of a smooth motion
//! it changes little, and a re-solve costs about as much as a frame.

/// How an [`super::Explorer`] refreshes its re-solves from answer to
/// answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Refresh {
    /// After the first answer, how many re-solves each answer makes anew
    /// (`None`: all of them).
    per_answer: Option<usize>,
    /// The re-solve the next answer makes anew first.
    next: usize,
}

impl Refresh {
    /// Every re-solve made anew at every answer.
    pub fn all() -> Self {
        Self {
            per_answer: None,
            next: 0,
        }
    }

    /// After the first answer, `count` re-solves made anew at each answer
    /// (at least one), in turn: with `n` re-solves an answer's columns are
    /// at most `ceil(n / count)` answers old.
    pub fn every(count: usize) -> Self {
        Self {
            per_answer: Some(count.max(1)),
            next: 0,
        }
    }

    /// How many re-solves each answer makes anew after the first (`None`:
    /// all).
    pub fn per_answer(&self) -> Option<usize> {
        self.per_answer
    }

    /// For an answer of `n` re-solves, whether each is made anew: all of
    /// them where the last answer's cannot be carried (`can_carry`: there
    /// was one, of the same re-solves), else `per_answer` of them from
    /// where the last answer stopped, round the list.
    pub(super) fn plan(&mut self, n: usize, can_carry: bool) -> Vec<bool> {
        match self.per_answer {
            Some(count) if can_carry && count < n => {
                let first = self.next % n;
                self.next = (first + count) % n;
                (0..n).map(|i| (i + n - first) % n < count).collect()
            }
            _ => {
                self.next = 0;
                vec![true; n]
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first answer makes every re-solve; after it each answer makes
    /// `count` of them in turn, so that every one is made once in
    /// `ceil(n / count)` answers; an answer that cannot carry the last one's
    /// makes them all again and starts the turn over.
    #[test]
    fn the_re_solves_are_made_in_turn() {
        let mut refresh = Refresh::every(3);
        assert_eq!(refresh.plan(7, false), vec![true; 7]);
        let mut made = [0; 7];
        for answer in 0..7 {
            let plan = refresh.plan(7, true);
            assert_eq!(plan.iter().filter(|&&f| f).count(), 3, "answer {answer}");
            for (i, fresh) in plan.iter().enumerate() {
                made[i] += usize::from(*fresh);
            }
            if answer == 2 {
                // Three answers of three cover seven.
                assert!(made.iter().all(|&m| m >= 1), "{made:?}");
            }
        }
        // 21 re-solves over seven: three each.
        assert_eq!(made, [3; 7]);
        assert_eq!(refresh.plan(7, false), vec![true; 7]);
        assert_eq!(refresh.plan(7, true)[..3], [true; 3]);
        assert_eq!(Refresh::every(7).plan(7, true), vec![true; 7]);
        assert_eq!(Refresh::all().plan(5, true), vec![true; 5]);
        assert_eq!(Refresh::every(0).per_answer(), Some(1));
    }
}
