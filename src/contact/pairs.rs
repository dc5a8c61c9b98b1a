//! Which body pairs can touch, with which friction, and which body is the slave of each pass.
//!
//! Kept as the scene's rule (every pair, the listed pairs, the role order), not as an n x n
//! table: a packing of N grains has N²/2 pairs, and tables over them grow past the memory of
//! the packings users run (doc/benchmarks.md, "Large packings").

use crate::precision::Real;
use std::cmp::Ordering;
use std::collections::HashMap;

/// What decides a pair's slave when the scene does not: the finer mesh (smaller length scale),
/// then the one with more boundary nodes, then the first in the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rank {
    pub length_scale: Real,
    pub boundary_nodes: usize,
}

#[derive(Debug, Clone)]
pub struct BodyPairs {
    ranks: Vec<Rank>,
    /// The friction of the pairs not listed, when every pair can touch (`contact.all_pairs`).
    every: Option<Real>,
    /// `[contact.pair]`s by (lower, higher) body index: friction, and the slave if chosen.
    listed: HashMap<(usize, usize), (Real, Option<usize>)>,
    /// Both passes of every pair (each body the slave once).
    two_pass: bool,
    /// Whether a body can be the slave, or the master, of a pass.
    slave: Vec<bool>,
    master: Vec<bool>,
}

impl BodyPairs {
    /// The pairs of bodies with these ranks: every pair with friction `every` when given, none
    /// otherwise until [`BodyPairs::list`]ed.
    pub fn new(ranks: Vec<Rank>, every: Option<Real>, two_pass: bool) -> Self {
        let n = ranks.len();
        let mut pairs = Self { ranks, every, listed: HashMap::new(), two_pass, slave: vec![false; n], master: vec![false; n] };
        if every.is_some() && n >= 2 {
            // The rule is an order: every body is the slave of its pair with the last body in
            // it, and the master of its pair with the first.
            let order = |a: &usize, b: &usize| pairs.before(*a, *b);
            let (first, last) = ((0..n).min_by(order).expect("two bodies"), (0..n).max_by(order).expect("two bodies"));
            for b in 0..n {
                pairs.slave[b] = two_pass || b != last;
                pairs.master[b] = two_pass || b != first;
            }
        }
        pairs
    }

    /// Lists the pair `a`, `b` with its friction and, when the scene names it, its slave.
    pub fn list(&mut self, a: usize, b: usize, friction: Real, slave: Option<usize>) {
        let key = (a.min(b), a.max(b));
        self.listed.insert(key, (friction, slave));
        let s = self.slave_of(key.0, key.1);
        let m = if s == key.0 { key.1 } else { key.0 };
        self.slave[s] = true;
        self.master[m] = true;
        if self.two_pass {
            self.slave[m] = true;
            self.master[s] = true;
        }
    }

    /// `a` comes before `b` in the role order: `a` is their pair's slave unless the scene says.
    fn before(&self, a: usize, b: usize) -> Ordering {
        let (ra, rb) = (self.ranks[a], self.ranks[b]);
        ra.length_scale.total_cmp(&rb.length_scale).then_with(|| rb.boundary_nodes.cmp(&ra.boundary_nodes)).then_with(|| a.cmp(&b))
    }

    /// The first pass's slave of the pair `a < b`.
    fn slave_of(&self, a: usize, b: usize) -> usize {
        match self.listed(a, b).and_then(|l| l.1) {
            Some(slave) => slave,
            None if self.before(a, b).is_lt() => a,
            None => b,
        }
    }

    /// The friction of the pair `a`, `b` (either order), `None` when they cannot touch.
    pub fn mu(&self, a: usize, b: usize) -> Option<Real> {
        if a == b {
            return None;
        }
        match self.listed(a.min(b), a.max(b)) {
            Some(&(friction, _)) => Some(friction),
            None => self.every,
        }
    }

    /// The listing of the pair `a < b`. A packing lists no pair, and its searches ask of every
    /// neighbour: no hashing then.
    fn listed(&self, a: usize, b: usize) -> Option<&(Real, Option<usize>)> {
        if self.listed.is_empty() {
            return None;
        }
        self.listed.get(&(a, b))
    }

    /// The friction of the pass with `slave`'s nodes on `master`'s facets, `None` when that pass
    /// is not done.
    pub fn friction(&self, slave: usize, master: usize) -> Option<Real> {
        let mu = self.mu(slave, master)?;
        (self.two_pass || self.slave_of(slave.min(master), slave.max(master)) == slave).then_some(mu)
    }

    /// That pass is the second of a two-pass pair: its points are dropped where they only repeat
    /// a first-pass point ([`super::detect::thin_second_pass`]).
    pub fn second(&self, slave: usize, master: usize) -> bool {
        self.two_pass && self.mu(slave, master).is_some() && self.slave_of(slave.min(master), slave.max(master)) != slave
    }

    /// False when `b` is the slave of no pass, so that detection skips its nodes. (True can
    /// also mean that a listed slave turned round every pass the rule gave `b`.)
    pub fn is_slave(&self, b: usize) -> bool {
        self.slave[b]
    }

    /// False when `b` is the master of no pass, so that detection skips its facets (true as
    /// in [`BodyPairs::is_slave`]).
    pub fn is_master(&self, b: usize) -> bool {
        self.master[b]
    }

    /// Whether any pair can touch.
    pub fn any(&self) -> bool {
        self.slave.iter().any(|&s| s)
    }

    /// Whether some pair has a second pass.
    pub fn any_second(&self) -> bool {
        self.two_pass && self.any()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The n x n tables this replaces, built as `build_contact` built them.
    fn tables(ranks: &[Rank], every: Option<Real>, listed: &[(usize, usize, Real, Option<usize>)], two_pass: bool) -> (Vec<Vec<Option<Real>>>, Vec<Vec<bool>>) {
        let n = ranks.len();
        let mut pairs = vec![vec![None; n]; n];
        let mut chosen = HashMap::new();
        for a in 0..n {
            for b in a + 1..n {
                pairs[a][b] = every;
            }
        }
        for &(a, b, mu, slave) in listed {
            pairs[a.min(b)][a.max(b)] = Some(mu);
            if let Some(s) = slave {
                chosen.insert((a.min(b), a.max(b)), s);
            }
        }
        let mut friction = vec![vec![None; n]; n];
        let mut second = vec![vec![false; n]; n];
        for a in 0..n {
            for b in a + 1..n {
                let Some(mu) = pairs[a][b] else { continue };
                let b_first = match chosen.get(&(a, b)) {
                    Some(&s) => s == b,
                    None => ranks[b].length_scale.total_cmp(&ranks[a].length_scale).then_with(|| ranks[a].boundary_nodes.cmp(&ranks[b].boundary_nodes)).is_lt(),
                };
                let (s, m) = if b_first { (b, a) } else { (a, b) };
                friction[s][m] = Some(mu);
                if two_pass {
                    friction[m][s] = Some(mu);
                    second[m][s] = true;
                }
            }
        }
        (friction, second)
    }

    #[test]
    fn the_rule_gives_the_tables_it_replaces() {
        // Ties in length scale and in boundary nodes, on purpose.
        let ranks: Vec<Rank> = [(0.1, 8), (0.2, 8), (0.1, 12), (0.1, 8), (0.3, 4), (0.2, 9)].iter().map(|&(length_scale, boundary_nodes)| Rank { length_scale, boundary_nodes }).collect();
        let n = ranks.len();
        let listed = [(4, 1, 0.7, None), (2, 0, 0.1, Some(2)), (3, 5, 0.0, Some(5))];
        for every in [None, Some(0.3)] {
            for two_pass in [false, true] {
                let mut pairs = BodyPairs::new(ranks.clone(), every, two_pass);
                for &(a, b, mu, slave) in &listed {
                    pairs.list(a, b, mu, slave);
                }
                let (friction, second) = tables(&ranks, every, &listed, two_pass);
                for s in 0..n {
                    for m in 0..n {
                        assert_eq!(pairs.friction(s, m), friction[s][m], "friction[{s}][{m}], every {every:?}, two passes {two_pass}");
                        assert_eq!(pairs.second(s, m), second[s][m], "second[{s}][{m}], every {every:?}, two passes {two_pass}");
                        assert_eq!(pairs.mu(s, m).is_some(), friction[s][m].is_some() || friction[m][s].is_some());
                    }
                    // Exact here: no listed slave turns round every pass of a body.
                    assert_eq!(pairs.is_slave(s), friction[s].iter().any(Option::is_some), "slave {s}");
                    assert_eq!(pairs.is_master(s), friction.iter().any(|row| row[s].is_some()), "master {s}");
                }
                assert_eq!(pairs.any_second(), second.iter().flatten().any(|&x| x));
            }
        }
        let none = BodyPairs::new(ranks, None, true);
        assert!(!none.any() && !none.any_second());
    }
}
