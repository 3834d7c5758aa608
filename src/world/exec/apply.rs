//! The change list an action produces and how it is applied: in order, set-valued targets resolved
//! when applied (as the simulator's state changers do), with the net effects logged.

use super::*;

/// One change to the state. Set-valued targets are resolved when applied, in order, as the
/// simulator's state changers are.
#[derive(Clone, Debug)]
pub(crate) enum Op {
    Add(Ix, Relation, Ix),
    /// Adds the edge both ways (CLOSE is symmetric).
    AddBoth(Ix, Relation, Ix),
    Remove(Ix, Relation, Ix),
    /// Removes every edge of these relations from the node, and (if `reverse`) to it.
    RemoveAll(Ix, &'static [Relation], bool),
    /// Character CLOSE (both ways) to every node INSIDE this one.
    CloseToInsideOf(Ix, Ix),
    /// Character CLOSE (both ways) to every node this one is ON.
    CloseToSupportsOf(Ix, Ix),
    /// Character CLOSE (both ways) to every non-room node this one is INSIDE.
    CloseToContainersOf(Ix, Ix),
    /// Character CLOSE (both ways) to every body part.
    CloseToBodyParts(Ix),
    /// Character FACING whatever this node faces (sitting on a sofa faces the sofa's TV).
    FaceAsIt(Ix, Ix),
    State(Ix, State, bool),
    GrabRecord(Ix, Option<(Ix, Relation)>),
}

impl World {
    /// Applies changes in order and returns their net effect.
    pub(crate) fn apply(&mut self, ops: &[Op]) -> Effects {
        let mut edges_before: BTreeMap<(Ix, Relation, Ix), bool> = BTreeMap::new();
        let mut states_before: BTreeMap<(Ix, State), bool> = BTreeMap::new();
        for op in ops {
            match *op {
                Op::Add(f, r, t) => self.logged_add(&mut edges_before, f, r, t),
                Op::AddBoth(f, r, t) => {
                    self.logged_add(&mut edges_before, f, r, t);
                    self.logged_add(&mut edges_before, t, r, f);
                }
                Op::Remove(f, r, t) => self.logged_remove(&mut edges_before, f, r, t),
                Op::RemoveAll(n, rels, reverse) => {
                    for &r in rels {
                        let outs: Vec<Ix> = self.targets(n, r).collect();
                        for t in outs {
                            self.logged_remove(&mut edges_before, n, r, t);
                        }
                        if reverse {
                            let ins: Vec<Ix> = self.sources(n, r).collect();
                            for f in ins {
                                self.logged_remove(&mut edges_before, f, r, n);
                            }
                        }
                    }
                }
                Op::CloseToInsideOf(c, n) => {
                    let xs: Vec<Ix> = self.sources(n, Relation::Inside).collect();
                    self.close_to_all(&mut edges_before, c, &xs);
                }
                Op::CloseToSupportsOf(c, n) => {
                    let xs: Vec<Ix> = self.targets(n, Relation::On).collect();
                    self.close_to_all(&mut edges_before, c, &xs);
                }
                Op::CloseToContainersOf(c, n) => {
                    let xs: Vec<Ix> = self.targets(n, Relation::Inside).filter(|&x| !self.is_room_ix(x)).collect();
                    self.close_to_all(&mut edges_before, c, &xs);
                }
                Op::CloseToBodyParts(c) => {
                    let xs = self.st.body_parts.clone();
                    self.close_to_all(&mut edges_before, c, &xs);
                }
                Op::FaceAsIt(c, n) => {
                    let xs: Vec<Ix> = self.targets(n, Relation::Facing).collect();
                    for x in xs {
                        self.logged_add(&mut edges_before, c, Relation::Facing, x);
                    }
                }
                Op::State(n, s, on) => {
                    let cur = self.states_ix(n).contains(s);
                    states_before.entry((n, s)).or_insert(cur);
                    self.set_state(n, s, on);
                }
                Op::GrabRecord(n, rec) => match rec {
                    Some(v) => {
                        self.grabbed_from.insert(n, v);
                    }
                    None => {
                        self.grabbed_from.remove(&n);
                    }
                },
            }
        }
        let free = self.hands_free();
        self.history.character_hands_were_free |= free;
        self.history.character_held_something |= !free;
        let mut fx = Effects::default();
        for ((f, r, t), before) in edges_before {
            let now = self.has_ix(f, r, t);
            if now != before {
                let e = (self.id(f), r, self.id(t));
                if now {
                    fx.added.push(e)
                } else {
                    fx.removed.push(e)
                }
            }
        }
        for ((n, s), before) in states_before {
            let now = self.states_ix(n).contains(s);
            if now != before {
                if now {
                    fx.states_added.push((self.id(n), s))
                } else {
                    fx.states_removed.push((self.id(n), s))
                }
            }
        }
        fx.added.sort();
        fx.removed.sort();
        fx.states_added.sort();
        fx.states_removed.sort();
        fx
    }

    fn close_to_all(&mut self, log: &mut BTreeMap<(Ix, Relation, Ix), bool>, c: Ix, xs: &[Ix]) {
        for &x in xs {
            self.logged_add(log, c, Relation::Close, x);
            self.logged_add(log, x, Relation::Close, c);
        }
    }

    fn logged_add(&mut self, log: &mut BTreeMap<(Ix, Relation, Ix), bool>, f: Ix, r: Relation, t: Ix) {
        let cur = self.has_ix(f, r, t);
        log.entry((f, r, t)).or_insert(cur);
        self.add_edge(f, r, t);
    }

    fn logged_remove(&mut self, log: &mut BTreeMap<(Ix, Relation, Ix), bool>, f: Ix, r: Relation, t: Ix) {
        let cur = self.has_ix(f, r, t);
        log.entry((f, r, t)).or_insert(cur);
        self.remove_edge(f, r, t);
    }
}
