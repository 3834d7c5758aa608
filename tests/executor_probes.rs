//! Development probes of the executor's fidelity (ignored tests, outside the default test command):
//! the EAI gold programs from an unpacked copy of the scene graphs, and a differential run against
//! EAI's own executor. The product's gold evaluation is `step eval gold` (tests/eai_gold.rs); these only
//! report which steps fail and why.
//! Run: `WORLD_GOLD_GRAPHS=/tmp/.../init_and_final_graphs cargo test --test executor_probes -- --ignored --nocapture`
//! (the programs are read from `$STEP_VH_DATA/eai/executable_programs`).

#[cfg(test)]
mod tests {
    use std::path::Path;
    use step::program::parse_step_line;
    use step::world::World;

    #[test]
    #[ignore]
    fn gold_programs_execute() {
        let Ok(dir) = std::env::var("WORLD_GOLD_GRAPHS") else { return };
        let data = std::env::var("STEP_VH_DATA").unwrap_or_else(|_| "../shared/bench/virtualhome".into());
        let progs = Path::new(&data).join("eai/executable_programs");
        let progs = progs.as_path();
        let mut names: Vec<_> = std::fs::read_dir(progs).unwrap().map(|e| e.unwrap().file_name()).collect();
        names.sort();
        let (mut ok, mut total, mut load_ns, mut exec_ns, mut final_match, mut build_ns) =
            (0, 0, 0u128, 0u128, 0, 0u128);
        for n in names {
            let n = n.to_string_lossy().to_string();
            let stem = n.trim_end_matches(".txt");
            let text = std::fs::read_to_string(progs.join(&n)).unwrap();
            let t0 = std::time::Instant::now();
            let scene = step::world::read_scene(&Path::new(&dir).join(format!("{stem}.json"))).unwrap();
            let tb = std::time::Instant::now();
            let mut w = World::from_graph(&scene.init, stem).unwrap();
            build_ns += tb.elapsed().as_nanos();
            load_ns += t0.elapsed().as_nanos();
            if total == 0 {
                let tc = std::time::Instant::now();
                for _ in 0..1000 {
                    std::hint::black_box(w.clone());
                }
                println!(
                    "clone: {:.1} us/clone ({} nodes, {} edges)",
                    tc.elapsed().as_nanos() as f64 / 1e6,
                    w.len(),
                    w.edge_count()
                );
                let tf = std::time::Instant::now();
                let f = w.feasible_actions();
                println!("feasible_actions: {} actions in {:.1} ms", f.len(), tf.elapsed().as_nanos() as f64 / 1e6);
            }
            total += 1;
            let t1 = std::time::Instant::now();
            let mut failed = None;
            for line in text.lines().filter(|l| l.trim_start().starts_with('[')) {
                let a = parse_step_line(line).unwrap();
                match w.execute(&a) {
                    Ok(fx) => {
                        if std::env::var("WORLD_GOLD_TRACE").is_ok_and(|t| t == stem) {
                            println!(
                                "{a}: +{:?} -{:?} +{:?} -{:?}",
                                fx.added, fx.removed, fx.states_added, fx.states_removed
                            );
                        }
                    }
                    Err(e) if e.eai_kind == step::world::FailureKind::AdditionalStep => {
                        println!("{stem}: skipped (additional): {} [{}]", e.message, e.kind)
                    }
                    Err(e) => {
                        failed = Some(format!("{} [{} / eai {}]", e.message, e.kind, e.eai_kind));
                        break;
                    }
                }
            }
            exec_ns += t1.elapsed().as_nanos();
            match failed {
                None => {
                    ok += 1;
                    if let Some(fg) = scene.final_graph {
                        let f = World::from_graph(&fg, "final").unwrap();
                        let (a, b) = (w.edges(), f.edges());
                        let sa: Vec<_> = w.nodes().map(|n| (n.id, n.states)).collect();
                        let sb: Vec<_> = f.nodes().map(|n| (n.id, n.states)).collect();
                        if a == b && sa == sb {
                            final_match += 1;
                        } else if std::env::var("WORLD_GOLD_DIFF").is_ok() {
                            let extra: Vec<_> = a.iter().filter(|e| !b.contains(e)).take(6).collect();
                            let miss: Vec<_> = b.iter().filter(|e| !a.contains(e)).take(6).collect();
                            let sd: Vec<_> = sa.iter().zip(&sb).filter(|(x, y)| x != y).take(4).collect();
                            println!("{stem}: final differs: ours-only {extra:?} theirs-only {miss:?} states {sd:?}");
                        }
                    }
                }
                Some(m) => println!("{stem}: FAIL {m}"),
            }
        }
        println!(
            "executed {ok}/{total}; final graph identical {final_match}; read+parse+build {:.1} ms total (World build {:.1} ms), exec {:.1} ms total",
            load_ns as f64 / 1e6,
            build_ns as f64 / 1e6,
            exec_ns as f64 / 1e6
        );
        assert_eq!(ok, total, "every gold program executes");
    }
}

/// Differential probe (ignored test): runs plans from `WORLD_DIFF_PLANS` (a JSON list of
/// `{file, lines}`) and writes each plan's per-step outcome in EAI's error codes (0 wrong order,
/// 1 missing step, 2 affordance, 3 unknown object, 4 already satisfied) and its final non-CLOSE
/// edges and states to `WORLD_DIFF_OUT`, for comparison with EAI's own executor run on the same plans.
#[cfg(test)]
mod diff {
    use serde_json::{json, Value};
    use std::path::Path;
    use step::program::parse_step_line;
    use step::world::{FailureKind, World};

    #[test]
    #[ignore]
    fn differential_plans() {
        let (Ok(plans), Ok(out), Ok(dir)) =
            (std::env::var("WORLD_DIFF_PLANS"), std::env::var("WORLD_DIFF_OUT"), std::env::var("WORLD_GOLD_GRAPHS"))
        else {
            return;
        };
        let plans: Vec<Value> = serde_json::from_str(&std::fs::read_to_string(plans).unwrap()).unwrap();
        let mut results = Vec::new();
        let mut cache: Option<(String, World)> = None;
        for p in &plans {
            let file = p["file"].as_str().unwrap().to_string();
            if cache.as_ref().is_none_or(|(f, _)| *f != file) {
                let w = World::load(&Path::new(&dir).join(format!("{file}.json"))).unwrap();
                cache = Some((file.clone(), w));
            }
            let mut w = cache.as_ref().unwrap().1.clone();
            let mut codes = Vec::new();
            for line in p["lines"].as_array().unwrap() {
                let Ok(a) = parse_step_line(line.as_str().unwrap()) else {
                    codes.push(json!("parse"));
                    break;
                };
                match w.execute(&a) {
                    Ok(_) => codes.push(json!("ok")),
                    Err(e) => {
                        let code = match e.eai_kind {
                            FailureKind::WrongOrder => 0,
                            FailureKind::MissingStep => 1,
                            FailureKind::Affordance => 2,
                            FailureKind::UnknownObject | FailureKind::WrongArity => 3,
                            FailureKind::AdditionalStep => 4,
                        };
                        codes.push(json!(code));
                        if code != 4 {
                            break;
                        }
                    }
                }
            }
            let edges: Vec<Value> = w
                .edges()
                .into_iter()
                .filter(|e| e.1 != step::world::Relation::Close)
                .map(|(f, r, t)| json!([f, r.name(), t]))
                .collect();
            let states: Vec<Value> = w
                .nodes()
                .map(|n| {
                    let mut s: Vec<&str> = n.states.iter().map(|s| s.name()).collect();
                    s.sort();
                    json!([n.id, s])
                })
                .collect();
            let char_close = w.related(w.character(), step::world::Relation::Close);
            results.push(json!({"codes": codes, "edges": edges, "states": states, "char_close": char_close}));
        }
        std::fs::write(out, serde_json::to_string(&results).unwrap()).unwrap();
    }
}
