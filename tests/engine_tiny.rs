//! The whole decode pipeline on tiny random-weight models built here (both architectures): grammar
//! constrained generation parses, prefix reuse changes nothing but the work done, greedy decoding is
//! deterministic, and bad input is an error rather than a panic.

use std::path::PathBuf;

use step::action::{ObjRef, Verb};
use step::grammar::{parse_actions, ActionGrammar, VerbSpec};
use step::llm::chat::Message;
use step::llm::engine::{Engine, GenOptions, Generate, Prompt, StopReason, WarmSource};
use step::llm::gguf::GgufFile;
use step::llm::model::{argmax, Transformer};
use step::llm::sample::Sampling;
use step::llm::tiny::{write_tiny_gguf, TinySpec};
use step::llm::LlmError;

fn tiny(spec: TinySpec, dir: &tempfile::TempDir) -> PathBuf {
    let path = dir.path().join(format!("tiny-{}-{}.gguf", spec.arch, spec.seed));
    write_tiny_gguf(&spec, &path).unwrap();
    path
}

fn kitchen_grammar() -> String {
    let objects = vec![ObjRef::new("apple", 12), ObjRef::new("fridge", 5), ObjRef::new("kitchen_counter", 7)];
    let verbs = [Verb::Walk, Verb::Grab, Verb::Open, Verb::PutIn, Verb::Close, Verb::StandUp];
    ActionGrammar::new(verbs.into_iter().map(VerbSpec::from), objects).lines(1, 4).to_lark().unwrap()
}

fn chat(text: &str) -> Prompt {
    Prompt::Chat(vec![Message::system("You are a robot planner."), Message::user(text)])
}

#[test]
fn constrained_generation_parses_on_both_architectures() {
    let dir = tempfile::tempdir().unwrap();
    let lark = kitchen_grammar();
    for spec in [TinySpec::llama(), TinySpec::qwen2()] {
        let mut e = Engine::load(&tiny(spec, &dir)).unwrap();
        let opts = GenOptions { max_tokens: 200, ..Default::default() };
        let g = e.generate(&chat("put the apple in the fridge"), Some(&lark), &opts).unwrap();
        assert_ne!(g.stop, StopReason::MaxTokens, "{:?}", g.text);
        let actions = parse_actions(&g.text).unwrap_or_else(|err| panic!("output does not parse: {err:?}\n{}", g.text));
        assert!((1..=4).contains(&actions.len()), "{}", g.text);
        for a in &actions {
            assert_eq!(a.args.len(), a.verb.arity());
        }
    }
}

#[test]
fn sampled_constrained_generation_parses_for_many_seeds() {
    let dir = tempfile::tempdir().unwrap();
    let lark = kitchen_grammar();
    let mut e = Engine::load(&tiny(TinySpec::llama().with_seed(3), &dir)).unwrap();
    for seed in 0..20 {
        let opts = GenOptions {
            max_tokens: 200,
            sampling: Sampling::Sample { temperature: 1.5, top_p: 1.0, seed },
            reuse_prefix: true,
        };
        let g = e.generate(&chat("tidy the kitchen"), Some(&lark), &opts).unwrap();
        parse_actions(&g.text).unwrap_or_else(|err| panic!("seed {seed}: output does not parse: {err:?}\n{}", g.text));
    }
}

#[test]
fn prefix_reuse_gives_identical_outputs_and_skips_the_shared_prefix() {
    let dir = tempfile::tempdir().unwrap();
    let path = tiny(TinySpec::qwen2().with_seed(7), &dir);
    let lark = kitchen_grammar();
    let prompts: Vec<Prompt> = ["put the apple in the fridge", "put the apple on the counter", "open the fridge"]
        .iter()
        .map(|t| chat(t))
        .collect();
    let run = |reuse: bool| {
        let mut e = Engine::load(&path).unwrap();
        let opts = GenOptions { max_tokens: 120, sampling: Sampling::Greedy, reuse_prefix: reuse };
        prompts.iter().map(|p| e.generate(p, Some(&lark), &opts).unwrap()).collect::<Vec<_>>()
    };
    let with = run(true);
    let without = run(false);
    for (a, b) in with.iter().zip(&without) {
        assert_eq!(a.tokens, b.tokens);
        assert_eq!(b.reused_tokens, 0);
    }
    // The system message and chat scaffolding are shared: later calls reuse them.
    assert_eq!(with[0].reused_tokens, 0);
    assert!(with[1].reused_tokens > 5, "reused {}", with[1].reused_tokens);
    assert!(with[2].reused_tokens > 5, "reused {}", with[2].reused_tokens);
}

#[test]
fn greedy_is_deterministic_across_engines_and_calls() {
    let dir = tempfile::tempdir().unwrap();
    let path = tiny(TinySpec::llama().with_seed(11), &dir);
    let opts = GenOptions { max_tokens: 24, ..Default::default() };
    let mut a = Engine::load(&path).unwrap();
    let mut b = Engine::load(&path).unwrap();
    let p = Prompt::Text("WALK to the fridge".into());
    let x = a.generate(&p, None, &opts).unwrap();
    let y = b.generate(&p, None, &opts).unwrap();
    let z = a.generate(&p, None, &opts).unwrap();
    assert_eq!(x.tokens, y.tokens);
    assert_eq!(x.tokens, z.tokens);
    assert!(!x.tokens.is_empty());
}

#[test]
fn forced_tokens_are_fast_forwarded() {
    // A grammar with a single sentence: every token is forced, none is chosen by the model.
    let dir = tempfile::tempdir().unwrap();
    let mut e = Engine::load(&tiny(TinySpec::llama(), &dir)).unwrap();
    let g = e.generate(&chat("go"), Some("start: \"[WALK] <fridge> (5)\""), &GenOptions::default()).unwrap();
    assert_eq!(g.text, "[WALK] <fridge> (5)");
    assert_eq!(g.forced_tokens, g.tokens.len());
    assert_eq!(g.stop, StopReason::GrammarComplete);
    assert!(g.timings.mask_us.is_empty(), "no mask should be computed when all is forced");
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let mut e = Engine::load(&tiny(TinySpec::llama(), &dir)).unwrap();
    let opts = GenOptions { max_tokens: 8, ..Default::default() };
    let err = e.generate(&chat("x"), Some("start: (("), &opts).err().unwrap().to_string();
    assert!(err.contains("grammar"), "{err}");
    // A grammar that needs more tokens than allowed is an error, not an unparseable output.
    let err = e
        .generate(&chat("x"), Some("start: /[a-z]{40}/"), &GenOptions { max_tokens: 3, ..Default::default() })
        .err()
        .unwrap();
    match &err {
        LlmError::TokenBudget { max_tokens: 3, so_far } => assert!(!so_far.is_empty(), "{err}"),
        other => panic!("expected a token-budget error, got {other}"),
    }
    assert!(err.to_string().contains("not complete after 3 tokens"), "{err}");
    // Not a GGUF file.
    let txt = dir.path().join("model.gguf");
    std::fs::write(&txt, "hello").unwrap();
    let err = Engine::load(&txt).err().unwrap().to_string();
    assert!(err.contains("not a GGUF"), "{err}");
}

#[test]
fn same_output_with_one_and_two_threads() {
    // candle sizes its thread pool once per process, so each thread count runs in its own process.
    let dir = tempfile::tempdir().unwrap();
    let path = tiny(TinySpec::qwen2().with_seed(5), &dir);
    let grammar = dir.path().join("g.lark");
    std::fs::write(&grammar, kitchen_grammar()).unwrap();
    let run = |threads: &str| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_step"))
            .args(["generate", "--threads", threads, "--max-tokens", "64", "--prompt", "open the fridge"])
            .arg("--model")
            .arg(&path)
            .arg("--grammar")
            .arg(&grammar)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap()
    };
    let one = run("1");
    assert_eq!(one, run("2"));
    assert!(parse_actions(one.trim_end()).is_ok(), "{one}");
}

#[test]
fn a_full_context_stops_with_the_text_so_far() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = TinySpec::qwen2().with_seed(2);
    spec.context_length = 24;
    let mut e = Engine::load(&tiny(spec, &dir)).unwrap();
    let prompt = Prompt::Text("open the fridge".into());
    let prompt_tokens = e.tokenizer().encode("open the fridge").unwrap().len();
    assert!(prompt_tokens < 24, "the prompt must leave room: {prompt_tokens}");
    let opts = GenOptions { max_tokens: 100, ..Default::default() };
    let g = e.generate(&prompt, Some("start: /[a-z]{60}/"), &opts).unwrap();
    assert_eq!(g.stop, StopReason::Context, "{g:?}");
    assert_eq!(g.prompt_tokens + g.tokens.len(), 25, "every position is used, and the last token kept");
    assert!(!g.text.is_empty() && g.text.chars().all(|c| c.is_ascii_lowercase()), "{:?}", g.text);
    // A prompt longer than the whole context is an error that says so.
    let long = Prompt::Text("open the fridge ".repeat(20));
    let err = e.generate(&long, None, &opts).err().unwrap();
    assert!(matches!(err, LlmError::PromptTooLong { context: 24, .. }), "{err}");
}

#[test]
fn scoring_a_list_shares_work_but_gives_each_line_its_own_score() {
    let dir = tempfile::tempdir().unwrap();
    let lines: Vec<String> = ["action: [WALK] <apple> (12)", "action: [WALK] <fridge> (5)", "action: [GRAB] <apple> (12)", "done"]
        .map(String::from)
        .to_vec();
    for spec in [TinySpec::llama(), TinySpec::qwen2()] {
        let path = tiny(spec, &dir);
        let prompt = chat("put the apple in the fridge");
        let mut together = Engine::load(&path).unwrap();
        let all = together.score(&prompt, &lines).unwrap();
        assert_eq!(all.scores.len(), lines.len());
        // Shared beginnings ran once: fewer tokens than the lines have between them.
        let total: usize = all.scores.iter().map(|s| s.tokens).sum();
        assert!(all.run_tokens < total, "{} run of {total}", all.run_tokens);
        for (i, line) in lines.iter().enumerate() {
            let mut alone = Engine::load(&path).unwrap();
            let one = alone.score(&prompt, std::slice::from_ref(line)).unwrap().scores[0];
            let s = all.scores[i];
            assert_eq!(s.tokens, one.tokens, "{line}");
            assert!((s.logprob - one.logprob).abs() < 1e-3, "{line}: {} together, {} alone", s.logprob, one.logprob);
            assert!(s.logprob < 0.0 && s.logprob.is_finite(), "{line}: {}", s.logprob);
        }
        // A generation after scoring is the same as on a fresh engine (the cache stays consistent).
        let opts = GenOptions { max_tokens: 8, ..Default::default() };
        let after = together.generate(&prompt, None, &opts).unwrap();
        let fresh = Engine::load(&path).unwrap().generate(&prompt, None, &opts).unwrap();
        assert_eq!(after.tokens, fresh.tokens);
        // An empty continuation is an error that says what to do.
        let err = together.score(&prompt, &[String::new()]).unwrap_err().to_string();
        assert!(err.contains("empty"), "{err}");
    }
}

/// The decode loop as first written, every token through its own forward pass (forced ones too):
/// the output and forced count the engine, which runs a chosen token and the tokens forced after it
/// in one pass, must reproduce.
fn one_token_at_a_time(path: &std::path::Path, prompt: &Prompt, lark: &str) -> (Vec<u32>, usize) {
    let e = Engine::load(path).unwrap();
    let ids = e.tokenizer().encode(&e.render(prompt).unwrap()).unwrap();
    let mut model = Transformer::load(&GgufFile::open(path).unwrap()).unwrap();
    let mut c = e.grammars().compile(lark).unwrap();
    let mut logits = model.forward(&ids).unwrap();
    let (mut out, mut forced) = (Vec::new(), 0);
    loop {
        let ff = c.forced_tokens().unwrap();
        forced += ff.len();
        out.extend_from_slice(&ff);
        if c.is_finished() {
            break;
        }
        for &t in &ff {
            logits = model.forward(&[t]).unwrap();
        }
        c.apply_mask(&mut logits).unwrap();
        let t = argmax(&logits).unwrap();
        if e.tokenizer().is_eos(t) {
            break;
        }
        c.commit(t).unwrap();
        out.push(t);
        if c.is_finished() {
            break;
        }
        logits = model.forward(&[t]).unwrap();
    }
    (out, forced)
}

#[test]
fn batched_forced_tokens_give_the_one_at_a_time_output() {
    let dir = tempfile::tempdir().unwrap();
    let lark = kitchen_grammar();
    for spec in [TinySpec::llama(), TinySpec::qwen2(), TinySpec::llama().with_seed(9), TinySpec::qwen2().with_seed(4)] {
        let path = tiny(spec, &dir);
        let mut e = Engine::load(&path).unwrap();
        for text in ["put the apple in the fridge", "open the fridge", "stand up"] {
            let prompt = chat(text);
            let opts = GenOptions { max_tokens: 200, ..Default::default() };
            let g = e.generate(&prompt, Some(&lark), &opts).unwrap();
            assert_ne!(g.stop, StopReason::MaxTokens, "{:?}", g.text);
            let (want, forced) = one_token_at_a_time(&path, &prompt, &lark);
            assert_eq!(g.tokens, want, "{text}: {:?}", g.text);
            assert_eq!(g.forced_tokens, forced, "{text}");
            // The decode speed counts every output token; the chosen-token rate leaves the forced out.
            assert!(g.output_tok_per_s() > g.decode_tok_per_s(), "{text}");
            assert!(forced > 0, "the kitchen grammar forces tokens ({text})");
            // The parts of the decode time are within it.
            let t = &g.timings;
            let parts = t.forward_ms
                + t.forced_forward_ms
                + t.mask_us.iter().sum::<f64>() / 1e3
                + t.grammar_ms
                + t.sample_ms
                + t.stream_ms;
            assert!(parts <= t.decode_ms + 1e-6, "{parts} ms of parts in {} ms", t.decode_ms);
            assert!(t.forced_forward_ms > 0.0 && t.mask_us.len() == g.tokens.len() - forced + (g.stop == StopReason::Eos) as usize);
        }
    }
}

#[test]
fn streamed_pieces_concatenate_to_the_final_text() {
    let dir = tempfile::tempdir().unwrap();
    let lark = kitchen_grammar();
    for spec in [TinySpec::llama().with_seed(6), TinySpec::qwen2().with_seed(8)] {
        let mut e = Engine::load(&tiny(spec, &dir)).unwrap();
        for grammar in [None, Some(lark.as_str())] {
            for seed in 0..6 {
                // Unconstrained random-weight models write arbitrary bytes: split characters included.
                let sampling =
                    if seed == 0 { Sampling::Greedy } else { Sampling::Sample { temperature: 1.2, top_p: 1.0, seed } };
                let opts = GenOptions { max_tokens: 80, sampling, reuse_prefix: true };
                let mut pieces: Vec<String> = Vec::new();
                let mut on_text = |p: &str| pieces.push(p.to_string());
                let g = e
                    .generate_streaming(&chat("tidy the kitchen"), grammar, &opts, Some(&mut on_text as &mut dyn FnMut(&str)))
                    .unwrap();
                assert_eq!(pieces.concat(), g.text, "seed {seed}, grammar {}", grammar.is_some());
                assert!(pieces.iter().all(|p| !p.is_empty()));
                if grammar.is_some() {
                    assert!(pieces.len() > 1, "pieces come as the text grows: {pieces:?}");
                }
            }
        }
    }
}

#[test]
fn a_prefix_snapshot_gives_the_bits_of_computing_the_prefix() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("prefix");
    for spec in [TinySpec::llama(), TinySpec::qwen2().with_seed(5)] {
        let path = tiny(spec, &dir);
        let system = vec![Message::system("You plan for a household robot, one step at a time. ".repeat(4))];
        let prompt = Prompt::Chat(vec![system[0].clone(), Message::user("put the apple in the fridge")]);
        let conts = ["[WALK] <apple> (12)\n".to_string(), "done\n".to_string()];
        let engine = |dir: Option<&std::path::Path>| {
            let mut e = Engine::load(&path).unwrap();
            e.set_prefix_dir(dir.map(|d| d.to_path_buf()));
            e
        };
        // No snapshot directory: warming does nothing, the call computes everything.
        let mut cold = engine(None);
        assert_eq!(cold.warm(&system).unwrap().source, WarmSource::None);
        let want = cold.score(&prompt, &conts).unwrap();
        assert_eq!(want.reused_tokens, 0);

        let mut first = engine(Some(&store));
        let w = first.warm(&system).unwrap();
        assert_eq!((w.source, w.note.as_deref()), (WarmSource::Computed, None));
        assert!(w.tokens > 50, "{w:?}");
        let snapshot = w.snapshot.clone().unwrap();
        assert!(snapshot.exists());
        let got = first.score(&prompt, &conts).unwrap();
        assert_eq!(got.scores, want.scores);
        assert_eq!(got.reused_tokens, w.tokens, "the prompt starts with the warmed tokens");
        assert_eq!(first.warm(&system).unwrap().source, WarmSource::Cached);

        // A new process reads the snapshot: the same numbers, bit for bit.
        let mut second = engine(Some(&store));
        let w2 = second.warm(&system).unwrap();
        assert_eq!((w2.source, &w2.snapshot), (WarmSource::Loaded, &w.snapshot));
        assert_eq!(second.score(&prompt, &conts).unwrap().scores, want.scores);

        // A damaged or truncated snapshot is said, recomputed and rewritten; never an error.
        let mut bytes = std::fs::read(&snapshot).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x40;
        std::fs::write(&snapshot, &bytes).unwrap();
        let mut third = engine(Some(&store));
        let w3 = third.warm(&system).unwrap();
        assert_eq!(w3.source, WarmSource::Computed);
        assert!(w3.note.as_deref().unwrap_or_default().contains("checksum"), "{w3:?}");
        assert_eq!(third.score(&prompt, &conts).unwrap().scores, want.scores);
        std::fs::write(&snapshot, &bytes[..mid]).unwrap();
        let w4 = engine(Some(&store)).warm(&system).unwrap();
        assert_eq!(w4.source, WarmSource::Computed);
        assert!(w4.note.as_deref().unwrap_or_default().contains("not a usable prefix snapshot"), "{w4:?}");
        assert_eq!(engine(Some(&store)).warm(&system).unwrap().source, WarmSource::Loaded);

        // Another system message is another snapshot.
        let other = vec![Message::system("You plan for a robot arm.")];
        let w5 = engine(Some(&store)).warm(&other).unwrap();
        assert_eq!(w5.source, WarmSource::Computed);
        assert_ne!(w5.snapshot, w.snapshot);
    }
}

#[test]
fn an_unwritable_prefix_directory_costs_time_not_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let path = tiny(TinySpec::llama(), &dir);
    // A file where the directory should be: nothing can be created under it.
    let blocked = dir.path().join("not-a-dir");
    std::fs::write(&blocked, b"x").unwrap();
    let mut e = Engine::load(&path).unwrap();
    e.set_prefix_dir(Some(blocked.join("prefix")));
    let system = vec![Message::system("You are a robot planner.")];
    let w = e.warm(&system).unwrap();
    assert_eq!(w.source, WarmSource::Computed);
    assert!(w.note.as_deref().unwrap_or_default().contains("cannot write the prefix snapshot"), "{w:?}");
    let p = Prompt::Chat(vec![system[0].clone(), Message::user("go")]);
    let g = e.generate(&p, None, &GenOptions { max_tokens: 4, ..Default::default() }).unwrap();
    assert!(g.reused_tokens > 0);
}

/// A task read ahead of the first call (`Generate::read`) is in memory only, the call then
/// computes just its own tail, and the numbers are those of reading nothing ahead.
#[test]
fn reading_a_task_ahead_changes_what_the_call_computes_not_its_numbers() {
    let dir = tempfile::tempdir().unwrap();
    for spec in [TinySpec::llama(), TinySpec::qwen2().with_seed(5)] {
        let path = tiny(spec, &dir);
        let system = vec![Message::system("You plan for a household robot, one step at a time.")];
        let task = "Task: put the apple in the fridge\nObjects: apple (12), fridge (10), kitchen (1)\n";
        let prompt = Prompt::Chat(vec![system[0].clone(), Message::user(format!("{task}State:\napple is ON table\nNext step?"))]);
        let conts = ["action:".to_string(), "done".to_string()];
        let want = Engine::load(&path).unwrap().score(&prompt, &conts).unwrap();

        let mut e = Engine::load(&path).unwrap();
        let r = e.read(&system, task).unwrap();
        assert_eq!(r.source, WarmSource::Computed);
        assert!(r.snapshot.is_none(), "a task is never kept on disk: {r:?}");
        let whole = e.tokenizer().encode(&e.render(&prompt).unwrap()).unwrap().len();
        let got = e.score(&prompt, &conts).unwrap();
        assert_eq!(got.scores, want.scores);
        // Everything read is reused (but a last token the prompt's next text may tokenize with).
        assert!(got.reused_tokens + 1 >= r.tokens && got.reused_tokens < whole, "{r:?}, {got:?}, {whole}");
        // Read again: nothing left to compute.
        let again = e.read(&system, task).unwrap();
        assert_eq!((again.source, again.tokens), (WarmSource::Cached, 0));
        // Another task after the same system message keeps the system message's tokens.
        let other = e.read(&system, "Task: wash the plate\n").unwrap();
        assert_eq!(other.source, WarmSource::Computed);
        assert!(other.tokens < r.tokens, "{other:?} after {r:?}");
    }
}
