//! Plans as text (placeholder).
