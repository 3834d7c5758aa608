//! Tests of the constraint core on small byte-level BPE tokenizers built here, with grammars written
//! out by hand: the runtime's tests know no domain. The helpers (test tokenizer, compiler, the random
//! "model" walk) are shared with the cross-layer tests in `crate::scene_grammar`, which run the
//! planner's grammar family through this runtime.

use std::collections::HashMap;
use std::sync::OnceLock;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use tokenizers::decoders::byte_level::ByteLevel as ByteLevelDecoder;
use tokenizers::models::bpe::{BpeTrainerBuilder, BPE};
use tokenizers::models::TrainerWrapper;
use tokenizers::pre_tokenizers::byte_level::ByteLevel;
use tokenizers::{AddedToken, Tokenizer};

use super::*;

pub(crate) const EOS: u32 = 2;

/// A free-text class of the kind planner grammars use for subgoals and reasons.
const TEST_TEXT_SLICE: &str = r"[A-Za-z0-9 ,.'_\-]{1,10}";

/// Corpus for the test tokenizer: script lines and words, so merges look like a real model's
/// (multi-character tokens spanning brackets, spaces and digits), not one byte per token.
fn corpus() -> Vec<String> {
    let verbs = ["WALK", "GRAB", "OPEN", "CLOSE", "PUTIN", "PUTBACK", "SWITCHON", "STANDUP", "FIND", "LOOKAT"];
    let objs = ["apple", "fridge", "kitchen_counter", "microwave", "cabinet", "table", "plate", "cup"];
    let mut lines = Vec::new();
    for (i, v) in verbs.iter().enumerate() {
        for (j, o) in objs.iter().enumerate() {
            let id = (i * 37 + j * 11) % 300;
            lines.push(format!("[{v}] <{o}> ({id})"));
            lines.push(format!("[{v}] <{o}> ({id}) <{}> ({})", objs[(j + 1) % objs.len()], id + 1));
        }
    }
    for s in [
        "subgoal: put the apple in the fridge",
        "verdict: decompose\nreason: the task needs several steps",
        "verdict: primitive\nreason: it's a single action, done.",
        "the quick brown fox jumps over the lazy dog 0123456789",
        "\"quoted\" back\\slash under_score it's",
    ] {
        lines.push(s.to_string());
    }
    lines
}

/// A GPT-2-style byte-level BPE tokenizer (all 256 bytes + merges learnt from [`corpus`]) with the
/// ChatML specials at ids 0..=2 like SmolLM2; EOS is `<|im_end|>` = 2.
fn build_test_tokenizer() -> Tokenizer {
    let trainer = BpeTrainerBuilder::new()
        .vocab_size(700)
        .min_frequency(2)
        .show_progress(false)
        .special_tokens(vec![
            AddedToken::from("<|endoftext|>", true),
            AddedToken::from("<|im_start|>", true),
            AddedToken::from("<|im_end|>", true),
        ])
        .initial_alphabet(ByteLevel::alphabet().into_iter().collect())
        .build();
    let mut trainer = TrainerWrapper::BpeTrainer(trainer);
    let mut tok = Tokenizer::new(BPE::default());
    tok.with_pre_tokenizer(Some(ByteLevel::new(false, true, true)));
    tok.with_decoder(Some(ByteLevelDecoder::new(false, true, true)));
    tok.train(&mut trainer, corpus().into_iter()).expect("training the test tokenizer");
    tok
}

pub(crate) fn test_tokenizer() -> &'static Arc<Tokenizer> {
    static TOK: OnceLock<Arc<Tokenizer>> = OnceLock::new();
    TOK.get_or_init(|| Arc::new(build_test_tokenizer()))
}

pub(crate) fn compiler() -> &'static GrammarCompiler {
    static C: OnceLock<GrammarCompiler> = OnceLock::new();
    C.get_or_init(|| {
        let tok = test_tokenizer();
        // Pad the logits width past the vocabulary, as real models do.
        // One slice for a free-text class, so the sliced mask path is exercised too.
        let slices = [TEST_TEXT_SLICE.to_string()];
        GrammarCompiler::with_slices(tok.clone(), tok.get_vocab_size(true) + 5, &[EOS], &slices).expect("test compiler")
    })
}

pub(crate) fn decode(tokens: &[u32]) -> String {
    test_tokenizer().decode(tokens, false).expect("decode")
}

/// Each token's raw bytes (from the byte-level vocabulary strings through GPT-2's byte map), so the
/// walks build their text incrementally, byte-exact even where a token splits a UTF-8 character.
pub(crate) fn token_bytes(t: u32) -> &'static [u8] {
    static TABLE: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let tok = test_tokenizer();
        let to_byte: HashMap<char, u8> =
            crate::llm::tokenizer::byte_to_unicode().iter().enumerate().map(|(b, &c)| (c, b as u8)).collect();
        (0..tok.get_vocab_size(true) as u32)
            .map(|t| {
                let s = tok.id_to_token(t).unwrap_or_default();
                s.chars()
                    .map(|c| to_byte.get(&c).copied())
                    .collect::<Option<Vec<u8>>>()
                    .unwrap_or_else(|| s.into_bytes())
            })
            .collect()
    });
    table.get(t as usize).map(Vec::as_slice).unwrap_or(&[])
}

#[test]
fn test_tokenizer_is_deterministic_and_byte_level() {
    let a = build_test_tokenizer();
    let b = test_tokenizer();
    assert_eq!(
        a.get_vocab(true).into_iter().collect::<std::collections::BTreeMap<_, _>>(),
        b.get_vocab(true).into_iter().collect::<std::collections::BTreeMap<_, _>>()
    );
    assert_eq!(b.token_to_id("<|im_end|>"), Some(EOS));
    let ids = b.encode("[GRAB] <apple> (12)", false).unwrap().get_ids().to_vec();
    assert!(ids.len() < "[GRAB] <apple> (12)".len(), "merges are learnt: {ids:?}");
    assert_eq!(decode(&ids), "[GRAB] <apple> (12)");
}

/// How a walk ended.
#[derive(Debug, PartialEq)]
pub(crate) enum End {
    Eos,
    Finished,
}

/// What a walk needs to know about the vocabulary.
pub(crate) struct Vocab<'a> {
    pub n_vocab: usize,
    /// The EOS id whose presence in the mask is checked at every step.
    pub eos: u32,
    /// All ids that end a generation.
    pub eos_all: Vec<u32>,
    /// A token's raw bytes.
    pub bytes: &'a dyn Fn(u32) -> Vec<u8>,
}

pub(crate) fn test_vocab() -> Vocab<'static> {
    static BYTES: fn(u32) -> Vec<u8> = |t| token_bytes(t).to_vec();
    Vocab { n_vocab: test_tokenizer().get_vocab_size(true) + 5, eos: EOS, eos_all: vec![EOS], bytes: &BYTES }
}

/// The decode loop with a random-weight "model": random logits per step from a seeded RNG, the mask
/// applied, a token sampled by softmax; forced tokens taken when offered (on a coin flip, so both
/// paths are exercised). Checks at every step that EOS is allowed exactly when `accepts(text)`.
/// Pushes the time of each mask computation (µs) to `mask_us`.
pub(crate) fn random_walk(
    c: &mut Constraint,
    rng: &mut StdRng,
    v: &Vocab,
    cap: usize,
    accepts: &dyn Fn(&str) -> bool,
    mask_us: &mut Vec<f64>,
) -> Result<(Vec<u32>, End), String> {
    let eos = v.eos;
    let mut out: Vec<u32> = Vec::new();
    let mut text: Vec<u8> = Vec::new();
    let mut logits = vec![0f32; v.n_vocab];
    while out.len() < cap {
        if c.is_finished() {
            let m = c.mask().map_err(|e| e.to_string())?;
            if m.iter().collect::<Vec<_>>() != v.eos_all {
                return Err(format!("after the end only EOS may be allowed, got {:?}", m.iter().collect::<Vec<_>>()));
            }
            return Ok((out, End::Finished));
        }
        if rng.random_bool(0.5) {
            let ff = c.forced_tokens().map_err(|e| e.to_string())?;
            if !ff.is_empty() {
                out.extend_from_slice(&ff);
                ff.iter().for_each(|&t| text.extend((v.bytes)(t)));
                continue;
            }
        }
        let t0 = std::time::Instant::now();
        let mask = c.mask().map_err(|e| e.to_string())?;
        mask_us.push(t0.elapsed().as_secs_f64() * 1e6);
        let text_s = String::from_utf8_lossy(&text);
        if mask.is_allowed(eos) != accepts(&text_s) {
            return Err(format!(
                "EOS allowed = {} but the checker says {} for {text_s:?}",
                mask.is_allowed(eos),
                accepts(&text_s)
            ));
        }
        if mask.is_allowed(eos) != c.is_accepting() {
            return Err(format!("is_accepting disagrees with the mask at {text_s:?}"));
        }
        for x in logits.iter_mut() {
            *x = rng.random_range(-4.0f32..4.0);
        }
        mask.apply_to_logits(&mut logits).map_err(|e| e.to_string())?;
        let max = logits.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
        let weights: Vec<f32> = logits.iter().map(|&l| (l - max).exp()).collect();
        let total: f32 = weights.iter().sum();
        let mut r = rng.random_range(0.0..total);
        let mut pick = None;
        for (i, &w) in weights.iter().enumerate() {
            if w > 0.0 {
                pick = Some(i as u32);
                if r < w {
                    break;
                }
                r -= w;
            }
        }
        let t = pick.ok_or("no token with positive weight")?;
        if !mask.is_allowed(t) {
            return Err(format!("sampled token {t} outside the mask"));
        }
        if v.eos_all.contains(&t) {
            return Ok((out, End::Eos));
        }
        c.commit(t).map_err(|e| e.to_string())?;
        out.push(t);
        text.extend((v.bytes)(t));
    }
    Err(format!("no end after {cap} tokens: {:?}", String::from_utf8_lossy(&text)))
}

/// The decode loop may compute a mask on another thread while the forward pass runs, and share one
/// compiler between threads.
#[test]
fn constraint_is_send_and_compiler_is_sync() {
    fn send<T: Send>() {}
    fn sync<T: Send + Sync>() {}
    send::<Constraint>();
    send::<TokenMask>();
    sync::<GrammarCompiler>();
}

#[test]
fn cache_compiles_once_and_hands_out_independent_constraints() {
    let tok = test_tokenizer();
    let c = GrammarCompiler::new(tok.clone(), tok.get_vocab_size(true), &[EOS]).unwrap();
    let g = r#"start: "[WALK] " ("<apple> (1)" | "<fridge> (2)")"#;
    let mut a = c.compile(g).unwrap();
    assert_eq!(c.cache_stats(), (1, 0));
    let mut b = c.compile(g).unwrap();
    assert_eq!(c.cache_stats(), (1, 1), "the second compile of the same text is a cache hit");
    c.compile(&format!("{g}\n")).unwrap();
    assert_eq!(c.cache_stats(), (2, 1), "a different text compiles");

    // Advancing one constraint leaves the other at the start.
    let ff = a.forced_tokens().unwrap();
    assert!(decode(&ff).starts_with("[WALK]"), "{:?}", decode(&ff));
    assert!(b.tokens().is_empty());
    let mb = b.mask().unwrap();
    let first = decode(&[mb.iter().next().unwrap()]);
    assert!("[WALK] ".starts_with(&first), "{first:?}");
}

#[test]
fn syntax_errors_name_the_line_and_the_problem() {
    let c = compiler();
    let e = c.compile("start: a\na: \"x\" (\n").err().unwrap().to_string();
    assert!(e.starts_with("grammar: invalid Lark grammar at line 2, column 9: Expected token ')'"), "{e}");
    let e = c.compile("start: \"a\" | b\n\nb: undefined_rule\n").err().unwrap().to_string();
    assert!(
        e.starts_with("grammar: invalid Lark grammar at line 3, column 4: unknown name: \"undefined_rule\""),
        "{e}"
    );
    let e = c.compile("notstart: \"a\"").err().unwrap().to_string();
    assert!(e.contains("grammar: invalid Lark grammar: no start rule found"), "{e}");
    let e = c.compile("start: /[abc/").err().unwrap().to_string();
    assert!(e.starts_with("grammar: invalid Lark grammar at line 1, column 8: invalid regex"), "{e}");
}

#[test]
fn an_empty_language_is_rejected_at_compile_time() {
    let e = compiler().compile("start: start \"a\"").err().unwrap().to_string();
    assert!(e.starts_with("grammar: grammar cannot be satisfied: its language is empty"), "{e}");
    assert!(!e.contains('\n'), "one line, no parser dump: {e}");
}

/// A vocabulary without 'z': a grammar needing 'z' first is rejected when compiled, one needing it
/// later fails at that position with a clear error (never an empty mask, a hang or a panic).
#[test]
fn grammars_this_vocabulary_cannot_produce_are_errors() {
    let json = r#"{
        "version": "1.0", "truncation": null, "padding": null, "normalizer": null, "post_processor": null,
        "added_tokens": [{"id": 2, "content": "<|im_end|>", "single_word": false, "lstrip": false,
                          "rstrip": false, "normalized": false, "special": true}],
        "pre_tokenizer": {"type": "ByteLevel", "add_prefix_space": false, "trim_offsets": true, "use_regex": true},
        "decoder": {"type": "ByteLevel", "add_prefix_space": false, "trim_offsets": true, "use_regex": true},
        "model": {"type": "BPE", "dropout": null, "unk_token": null, "continuing_subword_prefix": null,
                  "end_of_word_suffix": null, "fuse_unk": false, "byte_fallback": false,
                  "vocab": {"a": 0, "b": 1, "<|im_end|>": 2}, "merges": []}
    }"#;
    let tok: Tokenizer = json.parse().unwrap();
    let c = GrammarCompiler::new(Arc::new(tok), 3, &[2]).unwrap();

    let e = c.compile(r#"start: "z""#).err().unwrap().to_string();
    assert!(e.contains("cannot be satisfied"), "{e}");

    let mut k = c.compile(r#"start: "ab" "z""#).unwrap();
    let mut err = None;
    for _ in 0..10 {
        if let Err(e) = k.forced_tokens() {
            err = Some(e);
            break;
        }
        match k.mask() {
            Ok(m) => {
                let t = m.iter().next().unwrap();
                k.commit(t).unwrap();
            }
            Err(e) => {
                err = Some(e);
                break;
            }
        }
    }
    let e = err.expect("the dead end is reported").to_string();
    assert!(e.starts_with("decoding:") && e.contains("\"ab\"") && !e.contains('\n'), "{e}");
}

#[test]
fn commit_rejects_tokens_outside_the_mask_and_stays_usable() {
    let mut k = compiler().compile(r#"start: "[WALK] <apple> (1)" | "[WALK] <apple> (2)" "#).unwrap();
    let ff = k.forced_tokens().unwrap();
    assert!(!ff.is_empty());
    let m = k.mask().unwrap();
    let bad = (0..m.len() as u32).find(|&t| !m.is_allowed(t)).unwrap();
    let e = k.commit(bad).unwrap_err().to_string();
    assert!(e.contains("not allowed by the grammar"), "{e}");
    let e = k.commit(1_000_000).unwrap_err().to_string();
    assert!(e.contains("outside the vocabulary"), "{e}");
    assert!(!m.is_allowed(EOS), "EOS only where the grammar can end");
    // Still usable: finish the sentence.
    let mut rng = StdRng::seed_from_u64(1);
    let (rest, _) =
        random_walk(&mut k, &mut rng, &test_vocab(), 100, &|t: &str| t.ends_with(')'), &mut vec![]).unwrap();
    let all: Vec<u32> = ff.iter().chain(&rest).copied().collect();
    let text = decode(&all);
    assert!(text == "[WALK] <apple> (1)" || text == "[WALK] <apple> (2)", "{text:?}");
}

#[test]
fn finished_constraint_allows_only_eos() {
    let mut k = compiler().compile(r#"start: "ab""#).unwrap();
    let mut steps = 0;
    while !k.is_finished() && steps < 10 {
        steps += 1;
        if k.forced_tokens().unwrap().is_empty() {
            let t = k.mask().unwrap().iter().find(|&t| t != EOS).unwrap();
            k.commit(t).unwrap();
        }
    }
    assert!(k.is_finished() && k.is_accepting());
    assert_eq!(decode(k.tokens()), "ab");
    assert_eq!(k.mask().unwrap().iter().collect::<Vec<_>>(), vec![EOS]);
    assert!(k.forced_tokens().unwrap().is_empty());
    k.commit(EOS).unwrap();
    assert!(k.commit(5).unwrap_err().to_string().contains("only end-of-sequence"));
}

#[test]
fn eos_commit_ends_an_open_grammar() {
    let mut k = compiler().compile(r#"start: "a"+"#).unwrap();
    let a = test_tokenizer().token_to_id("a").unwrap();
    assert!(!k.mask().unwrap().is_allowed(EOS));
    k.commit(a).unwrap();
    assert!(k.is_accepting() && !k.is_finished());
    k.commit(EOS).unwrap();
    assert!(k.is_finished());
}

#[test]
fn apply_to_logits_masks_exactly_the_disallowed() {
    let mut k = compiler().compile(r#"start: /[a-m ]{1,5}/"#).unwrap();
    let m = k.mask().unwrap();
    assert!(m.count() > 10 && m.count() < m.len() / 2, "{}", m.count());
    let mut logits: Vec<f32> = (0..m.len()).map(|i| i as f32).collect();
    m.apply_to_logits(&mut logits).unwrap();
    for (i, &l) in logits.iter().enumerate() {
        if m.is_allowed(i as u32) {
            assert_eq!(l, i as f32);
        } else {
            assert_eq!(l, f32::NEG_INFINITY, "token {i}");
        }
    }
    assert_eq!(m.iter().count(), m.count());
    let e = m.apply_to_logits(&mut [0.0; 3]).unwrap_err().to_string();
    assert!(e.contains("logits have 3 entries"), "{e}");
}

#[test]
fn padded_logits_width_and_bad_eos_are_handled() {
    let tok = test_tokenizer();
    let v = tok.get_vocab_size(true);
    let c = compiler();
    let mut k = c.compile(r#"start: /[a-z]{1,3}/"#).unwrap();
    let m = k.mask().unwrap();
    assert_eq!(m.len(), v + 5);
    assert!((v as u32..(v + 5) as u32).all(|t| !m.is_allowed(t)), "padding ids are never allowed");
    assert!(GrammarCompiler::new(tok.clone(), v - 1, &[EOS]).err().unwrap().to_string().contains("smaller than"));
    assert!(GrammarCompiler::new(tok.clone(), v, &[]).err().unwrap().to_string().contains("no end-of-sequence"));
    assert!(GrammarCompiler::new(tok.clone(), v + 5, &[v as u32]).err().unwrap().to_string().contains("outside"));
}

/// Grammar problems the parser would only meet mid-generation are found without a model, in words
/// that say what to change; `|` inside strings and regexes is not an alternative.
#[test]
fn check_grammar_finds_limits_before_any_model_loads() {
    let wide: Vec<String> = (0..2100).map(|i| format!("\"w{i}\"")).collect();
    let e = check_grammar(&format!("start: {}\n", wide.join(" | "))).unwrap_err().to_string();
    assert!(e.contains("rule 'start' has 2100 alternatives") && e.contains("split it"), "{e}");
    let e = check_grammar("start: \"a\" start\n").unwrap_err().to_string();
    assert!(e.contains("never ends") || e.contains("cannot be satisfied"), "{e}");
    let e = check_grammar("start: ((\n").unwrap_err().to_string();
    assert!(e.contains("invalid Lark grammar"), "{e}");
    let piped: Vec<String> = (0..2100).map(|i| format!("a|{i}")).collect();
    check_grammar(&format!("start: \"{}\" | /x|y/\n", piped.join(""))).unwrap();
    check_grammar("start: line+\nline: (\"[WALK] <fridge> (5)\" | \"[OPEN] <fridge> (5)\") \"\\n\"\n").unwrap();
}

/// The compiler's token environment (sharing the engine's tokenizer) is the one
/// `toktrie_hf_tokenizers` builds: the same bytes for every id (padding included), the same eos
/// ids, the same tokenization of text with and without special tokens. On the test vocabulary and
/// on both real ones where installed.
#[test]
fn shared_token_env_equals_byte_tokenizer_env() {
    use crate::llm::gguf::test_models::{real_tokenizer, QWEN, SMOLLM2};
    let mut cases = vec![(test_tokenizer().clone(), vec![EOS])];
    for file in [SMOLLM2, QWEN] {
        if let Some(t) = real_tokenizer(file) {
            cases.push((t.shared_tokenizer().clone(), t.eos_ids().to_vec()));
        }
    }
    let texts: [&[u8]; 4] = [
        b"[WALK] <apple> (12)\n",
        "caf\u{e9} 123 \u{1f600} x".as_bytes(),
        b"<|im_start|>user\nhi<|im_end|>",
        b"\xff<|im_end|>a",
    ];
    for (tok, eos) in cases {
        let n_vocab = tok.get_vocab_size(true) + 3;
        let ours = SharedTokEnv::build(tok.clone(), n_vocab, &eos).unwrap();
        let mut bt = ByteTokenizer::from_tokenizer((*tok).clone()).unwrap();
        bt.set_eos_tokens(&eos);
        let theirs = bt.into_tok_env(Some(n_vocab)).unwrap();
        let (a, b) = (ours.tok_trie(), theirs.tok_trie());
        assert_eq!(a.vocab_size(), b.vocab_size());
        assert_eq!((a.eos_token(), a.eos_tokens()), (b.eos_token(), b.eos_tokens()));
        assert!((0..n_vocab as u32).all(|t| a.token(t) == b.token(t)), "token bytes differ");
        for s in texts {
            assert_eq!(ours.tokenize_bytes(s), theirs.tokenize_bytes(s), "{s:?}");
            assert_eq!(ours.tokenize_bytes_special(s), theirs.tokenize_bytes_special(s), "{s:?}");
            assert_eq!(ours.tokenize_bytes_marker(s), theirs.tokenize_bytes_marker(s), "{s:?}");
        }
    }
}
