//! Preconditions several verbs share (close to it, a free hand, holding it, not inside something
//! closed, a property, standing), each failing with the words and facts the classifier needs.

use super::*;

impl World {
    /// VirtualHome's "close" with its loose rule: close to it, or close to something that is close
    /// to it or that it stands on.
    pub(crate) fn is_close(&self, node: Ix) -> bool {
        let c = self.char_ix();
        if self.has_ix(c, Relation::Close, node) {
            return true;
        }
        self.targets(c, Relation::Close)
            .any(|x| self.has_ix(x, Relation::Close, node) || self.has_ix(node, Relation::On, x))
    }

    /// INSIDE something (not a room) that is CLOSED.
    pub(super) fn inside_closed(&self, node: Ix) -> Option<Ix> {
        self.targets(node, Relation::Inside).find(|&x| !self.is_room_ix(x) && self.states_ix(x).contains(State::Closed))
    }

    pub(super) fn free_hand(&self) -> Option<Relation> {
        let c = self.char_ix();
        HANDS.iter().copied().find(|&h| self.targets(c, h).next().is_none())
    }

    pub(super) fn holding_hand(&self, node: Ix) -> Option<Relation> {
        let c = self.char_ix();
        HANDS.iter().copied().find(|&h| self.has_ix(c, h, node))
    }

    pub(super) fn is_facing(&self, node: Ix) -> bool {
        let c = self.char_ix();
        self.has_ix(c, Relation::Facing, node)
            || self.targets(c, Relation::Facing).any(|x| self.has_ix(x, Relation::Facing, node))
    }

    pub(super) fn lbl(&self, ix: Ix) -> String {
        self.label_ix(ix)
    }

    pub(super) fn need_close(&self, node: Ix) -> Result<(), Fail> {
        if self.is_close(node) {
            return Ok(());
        }
        let l = self.lbl(node);
        Err(Fail::new(MissingStep, format!("the robot is not close to {l}; WALK to {l} first"))
            .needs(false, Fact::Edge { from: self.character(), relation: Relation::Close, to: self.id(node) }))
    }

    pub(super) fn need_free_hand(&self) -> Result<Relation, Fail> {
        self.free_hand().ok_or_else(|| {
            let held: Vec<String> =
                self.held().iter().map(|&(_, id)| self.node(id).map(|n| n.label()).unwrap_or_default()).collect();
            Fail::new(
                MissingStep,
                format!(
                    "both hands are full (holding {}); PUTBACK, PUTIN or DROP one of them first",
                    held.join(" and ")
                ),
            )
            .needs(true, Fact::Holds { from: self.character(), to: None })
            .connective(Connective::Any)
        })
    }

    pub(super) fn need_holding(&self, node: Ix) -> Result<Relation, Fail> {
        self.holding_hand(node).ok_or_else(|| {
            let l = self.lbl(node);
            Fail::new(MissingStep, format!("the robot is not holding {l}; GRAB {l} first"))
                .needs(false, Fact::Holds { from: self.character(), to: Some(self.id(node)) })
        })
    }

    pub(super) fn need_not_inside_closed(&self, node: Ix) -> Result<(), Fail> {
        match self.inside_closed(node) {
            None => Ok(()),
            Some(box_ix) => {
                let b = self.lbl(box_ix);
                Err(Fail::new(
                    MissingStep,
                    format!("{} is inside {b}, which is CLOSED; OPEN {b} first", self.lbl(node)),
                )
                // EAI records the object's own OPEN state here.
                .needs(false, Fact::State { id: self.id(node), state: State::Open }))
            }
        }
    }

    pub(super) fn need_prop(&self, node: Ix, p: Property, what: &str) -> Result<(), Fail> {
        if self.props_ix(node).contains(p) {
            Ok(())
        } else {
            Err(Fail::new(Affordance, format!("{} {what} (it lacks {p})", self.lbl(node))))
        }
    }

    pub(super) fn not_sitting_or_lying(&self) -> Result<(), Fail> {
        let c = self.char_ix();
        let s = self.states_ix(c);
        if s.contains(State::Sitting) || s.contains(State::Lying) {
            let how = if s.contains(State::Sitting) { "sitting" } else { "lying" };
            let ch = self.character();
            return Err(Fail::new(MissingStep, format!("the robot is {how}; STANDUP first"))
                .needs(true, Fact::State { id: ch, state: State::Sitting })
                .needs(true, Fact::State { id: ch, state: State::Lying })
                .connective(Connective::All));
        }
        Ok(())
    }
}
