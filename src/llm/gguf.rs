//! GGUF files: architecture detection (temporary minimal version; replaced by the full loader).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arch { Llama, Qwen2 }
impl Arch {
    pub fn name(self) -> &'static str { match self { Arch::Llama => "llama", Arch::Qwen2 => "qwen2" } }
}
