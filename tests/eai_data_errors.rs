//! Damaged copies of EAI's data set: a read error is reported with the file's path, never taken for
//! "no plan". The copies link to the real data (needed; skipped with a note when absent, unless
//! STEP_REQUIRE_DATA=1) and replace one file.

use std::path::{Path, PathBuf};

use step::eval::{EaiData, TaskSource};

fn data() -> Option<PathBuf> {
    match EaiData::open(None) {
        Ok(d) => Some(d.root),
        Err(e) => {
            if std::env::var("STEP_REQUIRE_DATA").is_ok_and(|v| v == "1") {
                panic!("STEP_REQUIRE_DATA=1 but the data is missing: {e}");
            }
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "note: skipping the damaged-data tests: {e}");
            None
        }
    }
}

/// A data root whose eai/resources and scene archive link to the real ones, with an empty
/// executable_programs directory.
fn linked_copy(real: &Path, dir: &Path) -> PathBuf {
    let root = dir.join("vh");
    std::fs::create_dir_all(root.join("eai/executable_programs")).unwrap();
    std::os::unix::fs::symlink(real.join("eai/resources"), root.join("eai/resources")).unwrap();
    std::os::unix::fs::symlink(real.join("resources"), root.join("resources")).unwrap();
    std::os::unix::fs::symlink(
        real.join("eai/init_and_final_graphs.tar.xz"),
        root.join("eai/init_and_final_graphs.tar.xz"),
    )
    .unwrap();
    root
}

fn load(root: &Path, id: &str) -> Result<Vec<step::eval::Task>, step::eval::EvalError> {
    TaskSource { tasks_file: None, data: Some(root.to_path_buf()) }.load(Some(&[id.to_string()]))
}

#[test]
fn a_corrupted_gold_program_is_a_read_error_naming_the_file_not_no_plan() {
    let Some(real) = data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let root = linked_copy(&real, dir.path());
    // Random bytes that are not UTF-8.
    let bad = root.join("eai/executable_programs/file27_2.txt");
    std::fs::write(&bad, [0xff, 0xfe, 0x00, 0x9c, 0x80, 0x41, 0xc3]).unwrap();
    let e = load(&root, "27_2").err().expect("a corrupted program is an error").to_string();
    assert!(e.contains("file27_2.txt"), "{e}");
    // Without a program file the task loads, with no gold plan.
    std::fs::remove_file(&bad).unwrap();
    let tasks = load(&root, "27_2").unwrap();
    assert!(tasks[0].gold.is_none());
}

#[test]
fn a_missing_scene_archive_is_an_error_naming_its_path() {
    let Some(real) = data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let root = linked_copy(&real, dir.path());
    std::fs::remove_file(root.join("eai/init_and_final_graphs.tar.xz")).unwrap();
    let e = load(&root, "27_2").err().unwrap().to_string();
    assert!(e.contains("init_and_final_graphs.tar.xz"), "{e}");
    assert_eq!(e.matches("No such file").count(), 1, "the cause once: {e}");
}
