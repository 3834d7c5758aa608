//! Criterion micro-benchmarks of the runtime's three hot paths on a tiny random-weight model (always
//! available) and, when installed, on SmolLM2 and Qwen2.5-Coder-0.5B: one decode step, a prefill,
//! and one token mask.
//! `step bench llm` gives the whole-pipeline figures on a real model.

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use step::scene_grammar::demo_kitchen_grammar;
use step::llm::engine::Engine;
use step::llm::gguf::GgufFile;
use step::llm::model::Transformer;
use step::llm::tiny::{write_tiny_gguf, TinySpec};
use step::llm::tokenizer::GgufTokenizer;

fn models() -> Vec<(String, PathBuf)> {
    let dir = std::env::temp_dir().join("step-bench");
    std::fs::create_dir_all(&dir).unwrap();
    let tiny = dir.join("tiny-llama.gguf");
    write_tiny_gguf(&TinySpec::llama(), &tiny).unwrap();
    let mut v = vec![("tiny".to_string(), tiny)];
    let installed = [("smollm2", "SmolLM2-135M-Instruct.Q4_1.gguf"), ("qwen2.5-coder-0.5b", "Qwen2.5-Coder-0.5B-Instruct.Q4_K_M.gguf")];
    for (name, file) in installed {
        let real = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models").join(file);
        if real.exists() {
            v.push((name.to_string(), real));
        }
    }
    v
}

fn load(path: &PathBuf) -> (Transformer, GgufTokenizer) {
    let g = GgufFile::open(path).unwrap();
    let tok = GgufTokenizer::from_gguf(&g).unwrap();
    (Transformer::load(&g).unwrap(), tok)
}

fn prompt_ids(tok: &GgufTokenizer, n: usize) -> Vec<u32> {
    let text = "[WALK] <apple> (12)\n[GRAB] <apple> (12)\n[OPEN] <fridge> (10)\n".repeat(64);
    let mut ids = tok.encode(&text).unwrap();
    ids.truncate(n);
    ids
}

fn bench(c: &mut Criterion) {
    for (name, path) in models() {
        let (mut model, tok) = load(&path);
        let ids = prompt_ids(&tok, 128);
        c.bench_function(&format!("{name}/prefill_128"), |b| {
            b.iter(|| {
                model.truncate(0);
                model.forward(&ids).unwrap()
            })
        });
        model.truncate(0);
        model.forward(&ids).unwrap();
        c.bench_function(&format!("{name}/decode_step_at_128"), |b| {
            b.iter(|| {
                model.truncate(128);
                model.forward(&ids[..1]).unwrap()
            })
        });
        let engine = Engine::load(&path).unwrap();
        let lark = demo_kitchen_grammar().to_lark().unwrap();
        // The mask after "[WALK] <": a choice among every object of the scene.
        c.bench_function(&format!("{name}/mask_object_choice"), |b| {
            b.iter_batched(
                || {
                    let mut k = engine.grammars().compile(&lark).unwrap();
                    k.forced_tokens().unwrap();
                    let walk = tok.encode("[WALK] <").unwrap();
                    for t in walk {
                        if k.mask().unwrap().is_allowed(t) {
                            k.commit(t).unwrap();
                        }
                        k.forced_tokens().unwrap();
                    }
                    k
                },
                |mut k| k.mask().unwrap(),
                criterion::BatchSize::SmallInput,
            )
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
