//! Prompt rendering with the chat template stored in the GGUF (`tokenizer.chat_template`), through
//! a real Jinja engine (minijinja) set up as Hugging Face's `apply_chat_template` runs templates:
//! `trim_blocks` and `lstrip_blocks` on, Python string methods (pycompat), `raise_exception`, and the
//! variables `messages`, `add_generation_prompt`, `bos_token` and `eos_token`.
//!
//! Errors name the template (the GGUF file and key) and the line at fault.

use minijinja::{context, Environment, ErrorKind};
use serde::Serialize;

use super::error::{LlmError, Result};
use super::gguf::{GgufFile, Metadata};

/// The metadata key holding the chat template.
pub const CHAT_TEMPLATE_KEY: &str = "tokenizer.chat_template";

/// One chat turn. `role` is usually `system`, `user` or `assistant`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Message {
    pub role: String,
    pub content: String,
}

impl Message {
    pub fn new(role: impl Into<String>, content: impl Into<String>) -> Self {
        Message { role: role.into(), content: content.into() }
    }

    pub fn system(content: impl Into<String>) -> Self {
        Self::new("system", content)
    }

    pub fn user(content: impl Into<String>) -> Self {
        Self::new("user", content)
    }

    pub fn assistant(content: impl Into<String>) -> Self {
        Self::new("assistant", content)
    }
}

/// A compiled chat template.
#[derive(Debug)]
pub struct ChatTemplate {
    env: Environment<'static>,
    name: String,
    source: String,
    bos_token: String,
    eos_token: String,
}

impl ChatTemplate {
    /// The template of a GGUF model; `bos_token` / `eos_token` are filled in from its vocabulary.
    pub fn from_gguf(gguf: &GgufFile) -> Result<Self> {
        Self::from_metadata(gguf.metadata())
    }

    /// The template stored in a GGUF metadata map.
    pub fn from_metadata(md: Metadata<'_>) -> Result<Self> {
        let source = md.get_str(CHAT_TEMPLATE_KEY)?;
        let token = |key: &str| -> Result<String> {
            let Some(id) = md.opt_u32(key)? else {
                return Ok(String::new());
            };
            let tokens = md.get_str_array("tokenizer.ggml.tokens")?;
            Ok(tokens.get(id as usize).map(|s| s.to_string()).unwrap_or_default())
        };
        let name = format!("{}:{CHAT_TEMPLATE_KEY}", md.path().display());
        Self::new(
            &name,
            source,
            &token("tokenizer.ggml.bos_token_id")?,
            &token("tokenizer.ggml.eos_token_id")?,
        )
    }

    /// Compiles `source`; `name` identifies it in errors.
    pub fn new(name: &str, source: &str, bos_token: &str, eos_token: &str) -> Result<Self> {
        let mut env = Environment::new();
        env.set_trim_blocks(true);
        env.set_lstrip_blocks(true);
        env.set_unknown_method_callback(minijinja_contrib::pycompat::unknown_method_callback);
        env.add_function(
            "raise_exception",
            |msg: String| -> std::result::Result<String, minijinja::Error> {
                Err(minijinja::Error::new(
                    ErrorKind::InvalidOperation,
                    format!("the template raised: {msg}"),
                ))
            },
        );
        env.add_template_owned(name.to_string(), source.to_string())
            .map_err(|e| template_error(name, source, &e))?;
        Ok(ChatTemplate {
            env,
            name: name.to_string(),
            source: source.to_string(),
            bos_token: bos_token.to_string(),
            eos_token: eos_token.to_string(),
        })
    }

    /// Renders `messages`; with `add_generation_prompt` the text ends where the assistant's reply
    /// begins (`<|im_start|>assistant\n` for ChatML).
    pub fn render(&self, messages: &[Message], add_generation_prompt: bool) -> Result<String> {
        let tmpl = self
            .env
            .get_template(&self.name)
            .map_err(|e| template_error(&self.name, &self.source, &e))?;
        tmpl.render(context! {
            messages => messages,
            add_generation_prompt => add_generation_prompt,
            bos_token => &self.bos_token,
            eos_token => &self.eos_token,
        })
        .map_err(|e| template_error(&self.name, &self.source, &e))
    }

    /// The template's name in errors: `<file>:tokenizer.chat_template` for a GGUF's.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The Jinja source.
    pub fn source(&self) -> &str {
        &self.source
    }
}

/// "<name>, line N: <what>" followed by the offending source line.
fn template_error(name: &str, source: &str, e: &minijinja::Error) -> LlmError {
    let what = match e.detail() {
        Some(d) => format!("{}: {d}", e.kind()),
        None => e.kind().to_string(),
    };
    let msg = match e.line() {
        Some(line) => {
            let text = source.lines().nth(line.saturating_sub(1)).unwrap_or("").trim();
            let text: String = text.chars().take(120).collect();
            format!("{name}, line {line}: {what}\n  {line} | {text}")
        }
        None => format!("{name}: {what}"),
    };
    LlmError::Template(msg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::llm::gguf::test_models::{real_gguf, QWEN, SMOLLM2};
    use crate::llm::tiny::{write_tiny_gguf, TinySpec};

    fn conversation() -> Vec<Message> {
        vec![
            Message::system("Plan robot actions."),
            Message::user("Put the apple in the fridge."),
            Message::assistant("[WALK] <kitchen> (11)"),
            Message::user("Next?"),
        ]
    }

    const CHATML_CONVERSATION: &str = "<|im_start|>system\nPlan robot actions.<|im_end|>\n\
<|im_start|>user\nPut the apple in the fridge.<|im_end|>\n\
<|im_start|>assistant\n[WALK] <kitchen> (11)<|im_end|>\n\
<|im_start|>user\nNext?<|im_end|>\n";

    #[test]
    fn tiny_template_renders_chatml() {
        let dir = tempfile::tempdir().unwrap();
        for spec in [TinySpec::llama(), TinySpec::qwen2()] {
            let p = dir.path().join(format!("{}.gguf", spec.arch));
            write_tiny_gguf(&spec, &p).unwrap();
            let t = ChatTemplate::from_gguf(&GgufFile::open(&p).unwrap()).unwrap();
            assert!(t.name().ends_with(":tokenizer.chat_template"));
            assert_eq!(t.render(&conversation(), false).unwrap(), CHATML_CONVERSATION);
            let out = t.render(&[Message::user("Hi")], true).unwrap();
            assert_eq!(
                out,
                "<|im_start|>system\nYou are a robot task planner.<|im_end|>\n\
                 <|im_start|>user\nHi<|im_end|>\n<|im_start|>assistant\n"
            );
        }
    }

    #[test]
    fn smollm2_template_renders_chatml() {
        let Some(g) = real_gguf(SMOLLM2) else { return };
        let t = ChatTemplate::from_gguf(g).unwrap();
        assert_eq!(t.render(&conversation(), false).unwrap(), CHATML_CONVERSATION);
        // Without a system turn the template adds its own default one.
        let out = t.render(&[Message::user("Hi")], true).unwrap();
        assert_eq!(
            out,
            "<|im_start|>system\nYou are a helpful AI assistant named SmolLM, trained by Hugging Face<|im_end|>\n\
             <|im_start|>user\nHi<|im_end|>\n<|im_start|>assistant\n"
        );
    }

    #[test]
    fn qwen_template_renders_chatml() {
        let Some(g) = real_gguf(QWEN) else { return };
        let t = ChatTemplate::from_gguf(g).unwrap();
        assert_eq!(t.render(&conversation(), false).unwrap(), CHATML_CONVERSATION);
        let out = t.render(&[Message::user("Hi")], true).unwrap();
        assert_eq!(
            out,
            "<|im_start|>system\nYou are Qwen, created by Alibaba Cloud. You are a helpful assistant.<|im_end|>\n\
             <|im_start|>user\nHi<|im_end|>\n<|im_start|>assistant\n"
        );
    }

    #[test]
    fn python_string_methods_and_tokens_work() {
        let src = "{{ bos_token }}{% for m in messages %}{{ m.role.upper() }}:{{ m.content.strip() }}|{% endfor %}{{ eos_token }}";
        let t = ChatTemplate::new("test", src, "<s>", "</s>").unwrap();
        let out = t.render(&[Message::user("  hi  ")], false).unwrap();
        assert_eq!(out, "<s>USER:hi|</s>");
    }

    #[test]
    fn syntax_errors_name_template_and_line() {
        let src = "{% for m in messages %}\n{{ m.content }}\n{% endfro %}";
        let err = ChatTemplate::new("model.gguf:tokenizer.chat_template", src, "", "").unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, LlmError::Template(_)));
        assert!(
            msg.contains("model.gguf:tokenizer.chat_template") && msg.contains("line 3"),
            "{msg}"
        );
        assert!(msg.contains("endfro"), "{msg}");
    }

    #[test]
    fn runtime_errors_name_template_and_line() {
        let src = "{% if messages[0].role != 'system' %}\n{{ raise_exception('a system turn is required') }}\n{% endif %}";
        let t = ChatTemplate::new("strict", src, "", "").unwrap();
        let msg = t.render(&[Message::user("x")], true).unwrap_err().to_string();
        assert!(
            msg.contains("strict")
                && msg.contains("line 2")
                && msg.contains("a system turn is required"),
            "{msg}"
        );
        assert!(t.render(&[Message::system("s")], true).is_ok());
    }

    #[test]
    fn missing_template_names_the_key() {
        let map = std::collections::HashMap::new();
        let err = ChatTemplate::from_metadata(Metadata::new(std::path::Path::new("m.gguf"), &map))
            .unwrap_err();
        assert!(err.to_string().contains("tokenizer.chat_template"), "{err}");
    }
}
