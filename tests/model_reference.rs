//! Our forward pass against candle-transformers' reference implementations on the real models: the
//! same token ids must give the same next-token logits (to float tolerance). Also checks that the KV
//! cache gives the same logits whether a sequence is fed at once, token by token, or after truncation.

use std::path::PathBuf;

use candle_core::quantized::gguf_file;
use candle_core::{Device, Tensor};
use step::llm::gguf::{Arch, GgufFile};
use step::llm::model::{argmax, Transformer};

fn model(file: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models").join(file);
    if p.exists() {
        return Some(p);
    }
    if std::env::var("STEP_REQUIRE_MODELS").is_ok_and(|v| v == "1") {
        panic!("{} is missing and STEP_REQUIRE_MODELS=1: run models/install.sh --large", p.display());
    }
    eprintln!("skipped: {} not installed (models/install.sh)", p.display());
    None
}

fn load(path: &PathBuf, arch: Arch) -> Transformer {
    let g = GgufFile::open(path).unwrap();
    assert_eq!(g.arch(), arch);
    Transformer::load(&g).unwrap()
}

fn max_rel_diff(a: &[f32], b: &[f32]) -> f32 {
    let scale = b.iter().fold(0f32, |m, x| m.max(x.abs()));
    a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs())) / scale
}

const IDS: &[u32] = &[1, 504, 2000, 300, 17, 1203, 88, 4096, 23, 77];

fn reference_logits(path: &PathBuf, arch: Arch) -> Vec<f32> {
    let mut f = std::fs::File::open(path).unwrap();
    let ct = gguf_file::Content::read(&mut f).unwrap();
    let input = Tensor::new(IDS, &Device::Cpu).unwrap().unsqueeze(0).unwrap();
    let logits = match arch {
        Arch::Llama => {
            let mut m =
                candle_transformers::models::quantized_llama::ModelWeights::from_gguf(ct, &mut f, &Device::Cpu)
                    .unwrap();
            m.forward(&input, 0).unwrap()
        }
        Arch::Qwen2 => {
            let mut m =
                candle_transformers::models::quantized_qwen2::ModelWeights::from_gguf(ct, &mut f, &Device::Cpu)
                    .unwrap();
            m.forward(&input, 0).unwrap()
        }
    };
    logits.flatten_all().unwrap().to_vec1::<f32>().unwrap()
}

fn check_against_reference(file: &str, arch: Arch) {
    let Some(path) = model(file) else { return };
    let mut m = load(&path, arch);
    let ours = m.forward(IDS).unwrap();
    let theirs = reference_logits(&path, arch);
    assert_eq!(ours.len(), theirs.len());
    let d = max_rel_diff(&ours, &theirs);
    assert!(d < 2e-3, "{file}: logits differ from the reference by {d} (relative to the largest)");
    assert_eq!(argmax(&ours), argmax(&theirs));
}

#[test]
fn smollm2_matches_candle_quantized_llama() {
    check_against_reference("SmolLM2-135M-Instruct.Q4_1.gguf", Arch::Llama);
}

#[test]
fn qwen2_matches_candle_quantized_qwen2() {
    check_against_reference("Qwen2.5-Coder-0.5B-Instruct.Q4_K_M.gguf", Arch::Qwen2);
}

#[test]
fn cache_gives_the_same_logits_in_one_pass_step_by_step_and_after_truncation() {
    let Some(path) = model("SmolLM2-135M-Instruct.Q4_1.gguf") else { return };
    let mut m = load(&path, Arch::Llama);
    let whole = m.forward(IDS).unwrap();
    m.truncate(0);
    let mut stepwise = Vec::new();
    for &t in IDS {
        stepwise = m.forward(&[t]).unwrap();
    }
    assert!(max_rel_diff(&stepwise, &whole) < 1e-3);
    // Keep a prefix, feed a different continuation, then go back to the original suffix.
    m.truncate(4);
    m.forward(&[9, 9, 9]).unwrap();
    m.truncate(4);
    assert_eq!(m.cached_len(), 4);
    let again = m.forward(&IDS[4..]).unwrap();
    assert!(max_rel_diff(&again, &whole) < 1e-3);
}
