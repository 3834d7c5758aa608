//! One handler per verb, named after it (`walk`, `find`, `grab`, `open_close` for OPEN/CLOSE, `put`
//! for PUTBACK/PUTIN, `switch`, `plug`, …; the dispatch in the parent module maps every verb). Each
//! checks preconditions in VirtualHome/EAI's order and returns the changes, or a failure.

use super::*;

impl World {
    pub(super) fn walk(&self, node: Ix) -> Check {
        self.not_sitting_or_lying()?;
        let c = self.char_ix();
        let Some(room) = self.room_ix(node) else {
            return Err(Fail::new(
                Affordance,
                format!("{} is not in any room, so it cannot be reached", self.lbl(node)),
            ));
        };
        // Doors are never in the way: VirtualHome's closed-door check is disabled in EAI's executor.
        let old_room = self.room_ix(c);
        let held: Vec<Ix> = HANDS.iter().flat_map(|&h| self.targets(c, h)).collect();
        let mut ops = vec![Op::RemoveAll(c, WALK_CLEARS, true), Op::Add(c, Relation::Inside, room)];
        if room != node {
            ops.push(Op::CloseToContainersOf(c, node));
            ops.push(Op::CloseToBodyParts(c));
            ops.push(Op::AddBoth(c, Relation::Close, node));
        }
        for &h in &held {
            ops.push(Op::RemoveAll(h, WALK_CLEARS, true));
        }
        for &h in &held {
            ops.push(Op::AddBoth(c, Relation::Close, h));
            // Held objects land in the room the robot walked from (as the simulator does).
            if let Some(r) = old_room {
                ops.push(Op::Add(h, Relation::Inside, r));
            }
        }
        if self.props_ix(node).contains(Property::CanOpen) {
            ops.push(Op::CloseToInsideOf(c, node));
        }
        ops.push(Op::CloseToSupportsOf(c, node));
        Ok(ops)
    }

    pub(super) fn find(&self, node: Ix) -> Check {
        let c = self.char_ix();
        let worn = self.has_ix(node, Relation::On, c);
        if worn || self.props_ix(node).contains(Property::BodyPart) || self.is_close(node) {
            self.need_close(node)?;
            Ok(vec![Op::RemoveAll(c, FACING_ONLY, false), Op::AddBoth(c, Relation::Close, node)])
        } else {
            self.walk(node)
        }
    }

    pub(super) fn greet(&self, node: Ix) -> Check {
        self.need_prop(node, Property::Person, "is not a person")?;
        Ok(vec![])
    }

    pub(super) fn occupancy_ok(&self, node: Ix, lying: bool) -> Result<(), Fail> {
        let class = self.class_ix(node);
        let max = if lying {
            match class {
                "couch" | "bathtub" | "loveseat" | "sofa" => 2,
                "bed" => 3,
                _ => 1,
            }
        } else {
            match class {
                "couch" | "bed" | "sofa" => 4,
                "loveseat" | "pianobench" | "bench" => 2,
                _ => 1,
            }
        };
        let n = self.sources(node, Relation::On).count();
        if n >= max {
            let on: Vec<String> = self.sources(node, Relation::On).take(3).map(|x| self.lbl(x)).collect();
            return Err(Fail::new(
                MissingStep,
                format!("{} is occupied ({} on it); choose another place", self.lbl(node), on.join(", ")),
            ));
        }
        Ok(())
    }

    pub(super) fn sit(&self, node: Ix) -> Check {
        self.need_close(node)?;
        let c = self.char_ix();
        if self.states_ix(c).contains(State::Sitting) {
            return Err(Fail::new(AdditionalStep, "the robot is already sitting"));
        }
        self.need_prop(node, Property::Sittable, "cannot be sat on")?;
        self.occupancy_ok(node, false)?;
        Ok(vec![
            Op::Add(c, Relation::On, node),
            Op::FaceAsIt(c, node),
            Op::State(c, State::Lying, false),
            Op::State(c, State::Sitting, true),
        ])
    }

    pub(super) fn lie(&self, node: Ix) -> Check {
        self.need_close(node)?;
        let c = self.char_ix();
        if self.states_ix(c).contains(State::Lying) {
            return Err(Fail::new(AdditionalStep, "the robot is already lying"));
        }
        self.need_prop(node, Property::Lieable, "cannot be lain on")?;
        self.occupancy_ok(node, true)?;
        Ok(vec![Op::Add(c, Relation::On, node), Op::State(c, State::Sitting, false), Op::State(c, State::Lying, true)])
    }

    pub(super) fn standup(&self) -> Check {
        let c = self.char_ix();
        let s = self.states_ix(c);
        if !s.contains(State::Sitting) && !s.contains(State::Lying) {
            return Err(Fail::new(AdditionalStep, "the robot is not sitting or lying"));
        }
        // The simulator keeps the robot's ON edge to the seat; only the states change.
        Ok(vec![Op::State(c, State::Sitting, false), Op::State(c, State::Lying, false)])
    }

    pub(super) fn grab(&self, node: Ix) -> Check {
        let class = self.class_ix(node);
        if !self.props_ix(node).contains(Property::Grabbable) && class != "water" && class != "child" {
            return Err(Fail::new(Affordance, format!("{} cannot be grabbed (it lacks GRABBABLE)", self.lbl(node))));
        }
        if self.grabbed_from.contains_key(&node) {
            return Err(Fail::new(AdditionalStep, format!("{} is already held", self.lbl(node))));
        }
        self.need_close(node)?;
        self.need_not_inside_closed(node)?;
        let hand = self.need_free_hand()?;
        let c = self.char_ix();
        // Where it came from (first of ON, INSIDE, CLOSE that is not a room): PUTOBJBACK returns it
        // there, and the robot becomes close to it. The simulator takes the first member of a Python
        // set of ids, whose order follows `id & mask` for a table sized by the set's length; we take
        // the same order, so that gold programs end in the same state (measured: see world-status).
        let from = [Relation::On, Relation::Inside, Relation::Close].into_iter().find_map(|r| {
            let ids: Vec<Ix> = self.targets(node, r).collect();
            let mask = py_set_mask(ids.len());
            ids.into_iter()
                .filter(|&x| !self.is_room_ix(x))
                .min_by_key(|&x| (self.id(x) as u64 & mask, self.id(x)))
                .map(|x| (x, r))
        });
        let mut ops =
            vec![Op::RemoveAll(node, GRAB_CLEARS, true), Op::AddBoth(c, Relation::Close, node), Op::Add(c, hand, node)];
        if let Some(room) = self.room_ix(c) {
            ops.push(Op::Add(node, Relation::Inside, room));
        }
        if let Some((x, r)) = from {
            ops.push(Op::AddBoth(c, Relation::Close, x));
            ops.push(Op::GrabRecord(node, Some((x, r))));
        }
        Ok(ops)
    }

    pub(super) fn open_close(&self, node: Ix, close: bool) -> Check {
        let class = self.class_ix(node);
        if !self.props_ix(node).contains(Property::CanOpen) && class != "desk" && class != "window" {
            return Err(Fail::new(
                Affordance,
                format!("{} cannot be opened or closed (it lacks CAN_OPEN)", self.lbl(node)),
            ));
        }
        self.need_close(node)?;
        if !close {
            self.need_free_hand()?;
        }
        let s = self.states_ix(node);
        let l = self.lbl(node);
        if close && !s.contains(State::Open) {
            return Err(Fail::new(AdditionalStep, format!("{l} is not open (nothing to close)")));
        }
        if !close && !s.contains(State::Closed) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already open")));
        }
        if !close && s.contains(State::On) {
            return Err(Fail::new(MissingStep, format!("{l} is ON; SWITCHOFF {l} first"))
                .eai(AdditionalStep)
                .needs(false, Fact::State { id: self.id(node), state: State::Off }));
        }
        let (gone, new) = if close { (State::Open, State::Closed) } else { (State::Closed, State::Open) };
        Ok(vec![Op::State(node, gone, false), Op::State(node, new, true)])
    }

    /// PUTBACK / PUTIN / PUTOBJBACK's common check: holding it, close to the destination, and for
    /// INSIDE an open (or not openable) destination.
    pub(super) fn puttable(&self, obj: Ix, dest: Ix, r: Relation) -> Result<(), Fail> {
        self.need_holding(obj)?;
        self.need_close(dest)?;
        if r == Relation::Inside
            && self.props_ix(dest).contains(Property::CanOpen)
            && !self.states_ix(dest).contains(State::Open)
        {
            let d = self.lbl(dest);
            return Err(Fail::new(MissingStep, format!("{d} is CLOSED; OPEN {d} first"))
                .eai(Affordance)
                .needs(false, Fact::State { id: self.id(dest), state: State::Open }));
        }
        Ok(())
    }

    pub(super) fn put_ops(&self, obj: Ix, dest: Ix, r: Relation) -> Vec<Op> {
        let c = self.char_ix();
        vec![
            Op::Remove(c, Relation::HoldsLh, obj),
            Op::Remove(c, Relation::HoldsRh, obj),
            Op::AddBoth(c, Relation::Close, dest),
            Op::AddBoth(obj, Relation::Close, dest),
            Op::Add(obj, r, dest),
            Op::GrabRecord(obj, None),
        ]
    }

    pub(super) fn put(&self, obj: Ix, dest: Ix, r: Relation) -> Check {
        self.puttable(obj, dest, r)?;
        Ok(self.put_ops(obj, dest, r))
    }

    pub(super) fn putobjback(&self, obj: Ix) -> Check {
        let Some(&(dest, r)) = self.grabbed_from.get(&obj) else {
            let l = self.lbl(obj);
            return Err(Fail::new(MissingStep, format!("{l} was not grabbed from anywhere; GRAB {l} first"))
                .needs(false, Fact::Holds { from: self.character(), to: Some(self.id(obj)) }));
        };
        self.puttable(obj, dest, r)?;
        Ok(self.put_ops(obj, dest, r))
    }

    pub(super) fn switch(&self, node: Ix, on: bool) -> Check {
        self.need_prop(node, Property::HasSwitch, "has no switch")?;
        self.need_close(node)?;
        let s = self.states_ix(node);
        let l = self.lbl(node);
        if on && !s.contains(State::Off) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already on")));
        }
        if !on && !s.contains(State::On) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already off")));
        }
        if on && s.contains(State::PluggedOut) {
            return Err(Fail::new(MissingStep, format!("{l} is unplugged; PLUGIN {l} first"))
                .eai(AdditionalStep)
                .needs(false, Fact::State { id: self.id(node), state: State::PluggedIn }));
        }
        let (gone, new) = if on { (State::Off, State::On) } else { (State::On, State::Off) };
        Ok(vec![Op::State(node, gone, false), Op::State(node, new, true)])
    }

    pub(super) fn drink(&self, node: Ix) -> Check {
        let p = self.props_ix(node);
        if !p.contains(Property::Drinkable) && !p.contains(Property::Recipient) {
            return Err(Fail::new(Affordance, format!("{} is not something to drink from", self.lbl(node))));
        }
        self.need_holding(node)?;
        Ok(vec![])
    }

    pub(super) fn lookat(&self, node: Ix) -> Check {
        if !self.is_facing(node) {
            let l = self.lbl(node);
            return Err(Fail::new(MissingStep, format!("the robot is not facing {l}; TURNTO {l} first"))
                .needs(false, Fact::Edge { from: self.character(), relation: Relation::Facing, to: self.id(node) }));
        }
        Ok(vec![])
    }

    pub(super) fn wipe(&self, node: Ix) -> Check {
        self.need_close(node)?;
        if self.hands_free() {
            // (anything held wipes; naming a cloth, in the robot's room where there is one, lets
            // the way to a WIPE be found: "wipe the counter" is GRAB the rag first)
            let cloth = self.a_tool(Tool::Cloth, None, self.room_of(self.character()));
            let fix = match cloth.and_then(|k| self.ix(k)) {
                Some(k) => format!("GRAB {} first", self.lbl(k)),
                None => "GRAB a cloth (e.g. a rag or towel) first".to_string(),
            };
            return Err(Fail::new(MissingStep, format!("the robot holds nothing to wipe with; {fix}"))
                .needs(false, Fact::Holds { from: self.character(), to: cloth })
                .connective(Connective::Any));
        }
        Ok(clean(node))
    }

    pub(super) fn puton(&self, node: Ix) -> Check {
        self.need_holding(node)?;
        self.need_prop(node, Property::Clothes, "is not clothing")?;
        let c = self.char_ix();
        Ok(vec![
            Op::Add(node, Relation::On, c),
            Op::Remove(c, Relation::HoldsLh, node),
            Op::Remove(c, Relation::HoldsRh, node),
        ])
    }

    pub(super) fn putoff(&self, node: Ix) -> Check {
        let c = self.char_ix();
        if !self.has_ix(node, Relation::On, c) {
            return Err(Fail::new(MissingStep, format!("the robot is not wearing {}", self.lbl(node)))
                .needs(false, Fact::Edge { from: self.id(node), relation: Relation::On, to: self.character() }));
        }
        self.need_prop(node, Property::Clothes, "is not clothing")?;
        Ok(vec![Op::Remove(node, Relation::On, c)])
    }

    pub(super) fn drop_obj(&self, node: Ix) -> Check {
        self.need_holding(node)?;
        let c = self.char_ix();
        let mut ops = vec![Op::Remove(c, Relation::HoldsLh, node), Op::Remove(c, Relation::HoldsRh, node)];
        if let Some(room) = self.room_ix(c) {
            ops.push(Op::Add(node, Relation::Inside, room));
        }
        ops.push(Op::GrabRecord(node, None));
        Ok(ops)
    }

    pub(super) fn read(&self, node: Ix) -> Check {
        self.need_prop(node, Property::Readable, "cannot be read")?;
        self.need_holding(node)?;
        Ok(vec![])
    }

    pub(super) fn touch(&self, node: Ix) -> Check {
        self.need_close(node)?;
        self.need_not_inside_closed(node)?;
        Ok(vec![])
    }

    pub(super) fn pour(&self, src: Ix, dest: Ix) -> Check {
        let p = self.props_ix(src);
        if !p.contains(Property::Pourable) && !p.contains(Property::Drinkable) {
            return Err(Fail::new(Affordance, format!("{} cannot be poured", self.lbl(src))));
        }
        let dc = self.class_ix(dest);
        if !self.props_ix(dest).contains(Property::Recipient) && !matches!(dc, "hands_both" | "sponge" | "face") {
            return Err(Fail::new(
                Affordance,
                format!("{} cannot receive a pour (it lacks RECIPIENT)", self.lbl(dest)),
            ));
        }
        self.need_holding(src)?;
        self.need_close(dest)?;
        let mut ops = vec![Op::Add(src, Relation::Inside, dest)];
        if self.class_ix(src) == "water" {
            let c = self.char_ix();
            ops.push(Op::Remove(c, Relation::HoldsLh, src));
            ops.push(Op::Remove(c, Relation::HoldsRh, src));
        }
        Ok(ops)
    }

    pub(super) fn type_on(&self, node: Ix) -> Check {
        self.need_close(node)?;
        if self.class_ix(node) != "keyboard" {
            self.need_prop(node, Property::HasSwitch, "cannot be typed on")?;
        }
        Ok(vec![])
    }

    pub(super) fn watch(&self, node: Ix) -> Check {
        self.need_prop(node, Property::Lookable, "cannot be watched")?;
        let c = self.char_ix();
        let (cr, nr) = (self.room_ix(c), self.room_ix(node));
        if cr.is_none() || cr != nr {
            let l = self.lbl(node);
            let where_ = nr.map(|r| format!(" (it is in {})", self.lbl(r))).unwrap_or_default();
            return Err(Fail::new(MissingStep, format!("{l} is not in the robot's room{where_}; WALK to {l} first"))
                .eai(Affordance));
        }
        let l = self.lbl(node);
        let facing = Fact::Edge { from: self.character(), relation: Relation::Facing, to: self.id(node) };
        if !self.is_facing(node) {
            return Err(
                Fail::new(MissingStep, format!("the robot is not facing {l}; TURNTO {l} first")).needs(false, facing)
            );
        }
        let s = self.states_ix(c);
        if self.class_ix(node) != "computer"
            && (s.contains(State::Sitting) || s.contains(State::Lying))
            && !self.has_ix(c, Relation::Facing, node)
        {
            return Err(Fail::new(
                MissingStep,
                format!("the robot is not facing {l} from where it sits; TURNTO {l} first"),
            )
            .needs(false, facing));
        }
        self.need_not_inside_closed(node)?;
        Ok(vec![])
    }

    pub(super) fn move_obj(&self, node: Ix, verb: Verb) -> Check {
        let class = self.class_ix(node);
        // As in EAI: PUSH is never refused for lack of MOVABLE; chairs and curtains always move.
        if !self.props_ix(node).contains(Property::Movable)
            && verb != Verb::Push
            && class != "button"
            && class != "chair"
            && class != "curtain"
        {
            return Err(Fail::new(Affordance, format!("{} cannot be moved (it lacks MOVABLE)", self.lbl(node))));
        }
        self.need_close(node)?;
        self.need_not_inside_closed(node)?;
        self.need_free_hand()?;
        Ok(vec![])
    }

    pub(super) fn wash(&self, node: Ix) -> Check {
        self.need_close(node)?;
        Ok(clean(node))
    }

    pub(super) fn squeeze(&self, node: Ix) -> Check {
        self.need_free_hand()?;
        self.need_close(node)?;
        const SQUEEZABLE: &[&str] = &[
            "cleaning_solution",
            "tooth_paste",
            "shampoo",
            "food_peanut_butter",
            "dish_soap",
            "soap",
            "towel",
            "rag",
            "paper",
            "sponge",
            "food_lemon",
            "check",
        ];
        if !self.props_ix(node).contains(Property::Clothes) && !SQUEEZABLE.contains(&self.class_ix(node)) {
            return Err(Fail::new(Affordance, format!("{} cannot be squeezed", self.lbl(node))));
        }
        Ok(vec![])
    }

    pub(super) fn plug(&self, node: Ix, plug_in: bool) -> Check {
        self.need_prop(node, Property::HasPlug, "has no plug")?;
        self.need_close(node)?;
        self.need_free_hand()?;
        let s = self.states_ix(node);
        let l = self.lbl(node);
        if plug_in && !s.contains(State::PluggedOut) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already plugged in")));
        }
        if !plug_in && !s.contains(State::PluggedIn) {
            return Err(Fail::new(AdditionalStep, format!("{l} is already unplugged")));
        }
        // EAI lets PLUGOUT of an appliance that is ON go through.
        let (gone, new) =
            if plug_in { (State::PluggedOut, State::PluggedIn) } else { (State::PluggedIn, State::PluggedOut) };
        Ok(vec![Op::State(node, gone, false), Op::State(node, new, true)])
    }

    pub(super) fn cut(&self, node: Ix) -> Check {
        self.need_free_hand()?;
        self.need_close(node)?;
        self.need_prop(node, Property::Eatable, "is not food")?;
        self.need_prop(node, Property::Cuttable, "cannot be cut")?;
        let c = self.char_ix();
        let has_knife = HANDS.iter().flat_map(|&h| self.targets(c, h)).any(|x| self.class_ix(x).contains("knife"));
        if !has_knife {
            // (naming one, in the robot's room where there is one, lets the way to a CUT be
            // found: "cut the bread" is GRAB a knife first)
            let knife = self.a_tool(Tool::Knife, None, self.room_of(self.character()));
            let fix = match knife.and_then(|k| self.ix(k)) {
                Some(k) => format!("GRAB {} first", self.lbl(k)),
                None => "GRAB a knife first (the scene has none)".to_string(),
            };
            return Err(Fail::new(MissingStep, format!("the robot is not holding a knife; {fix}")));
        }
        Ok(vec![])
    }

    pub(super) fn eat(&self, node: Ix) -> Check {
        self.need_close(node)?;
        if self.props_ix(node).contains(Property::Eatable) {
            return Ok(vec![]);
        }
        // A plate is "eaten from" if something edible is on it.
        if self.sources(node, Relation::On).any(|x| self.props_ix(x).contains(Property::Eatable)) {
            return Ok(vec![]);
        }
        Err(Fail::new(Affordance, format!("{} is not food and has no food on it", self.lbl(node))))
    }

    pub(super) fn sleep(&self) -> Check {
        let c = self.char_ix();
        let s = self.states_ix(c);
        if !s.contains(State::Lying) && !s.contains(State::Sitting) {
            let ch = self.character();
            return Err(Fail::new(MissingStep, "the robot is not lying or sitting; LIE on a bed or SIT first")
                .needs(false, Fact::State { id: ch, state: State::Lying })
                .needs(false, Fact::State { id: ch, state: State::Sitting }));
        }
        Ok(vec![])
    }
}

/// The slot mask of a CPython set holding `n` small ints (table 8, grown ×4 used when 3/5 full).
fn py_set_mask(n: usize) -> u64 {
    let mut size: u64 = 8;
    while (n as u64) * 5 >= (size - 1) * 3 {
        let mut new = 8;
        while new <= (n as u64) * 4 {
            new <<= 1;
        }
        size = new.max(size * 2);
    }
    size - 1
}

fn clean(node: Ix) -> Vec<Op> {
    vec![Op::State(node, State::Dirty, false), Op::State(node, State::Clean, true)]
}
