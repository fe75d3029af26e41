//! Unit tests of `pipeline::stages`.

mod tests {
    use cloudcontrol::formats::FormatError;
    use cloudcontrol::pipeline::stages::*;

    #[test]
    fn finished_stages_are_skipped_and_changed_inputs_rerun() {
        let d = tempfile::tempdir().unwrap();
        let input = d.path().join("in.txt");
        std::fs::write(&input, "a").unwrap();
        let out = d.path().join("out");
        let run = |fail_second: bool| {
            let mut r = Runner::new(&out).unwrap();
            let a = r
                .stage("one", &Inputs::new().file(&input).param("k", &3), |dir| {
                    std::fs::write(dir.join("x.txt"), std::fs::read(&input).unwrap())
                        .map_err(|e| FormatError::io(dir, e).into())
                })
                .unwrap();
            let second = r.stage("two", &Inputs::new().file(&a), |dir| {
                if fail_second {
                    return Err(WorkError::Inconsistent("killed".into()));
                }
                std::fs::write(dir.join("y.txt"), "done")
                    .map_err(|e| FormatError::io(dir, e).into())
            });
            (r.ran.clone(), r.skipped.clone(), second.is_ok())
        };
        // A run that dies in stage two leaves stage one finished and no half-written two.
        assert_eq!(run(true), (vec!["one".to_string()], vec![], false));
        assert!(!out.join("two").exists());
        assert_eq!(
            names(&out),
            [MARKER, "one", "stages.json"],
            "one/, the marker and stages.json only"
        );
        // The rerun skips one and completes two.
        assert_eq!(
            run(false),
            (vec!["two".to_string()], vec!["one".to_string()], true)
        );
        assert_eq!(
            run(false),
            (vec![], vec!["one".to_string(), "two".to_string()], true)
        );
        // A changed input reruns one, and two follows because its input changed.
        std::fs::write(&input, "b").unwrap();
        assert_eq!(run(false).0, vec!["one".to_string(), "two".to_string()]);
        // Tampered outputs are redone.
        std::fs::write(out.join("two/y.txt"), "tampered").unwrap();
        assert_eq!(run(false).0, vec!["two".to_string()]);
    }

    fn names(dir: &std::path::Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn leftovers_of_a_killed_run_are_removed_and_a_busy_folder_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("out");
        // A run killed inside a stage (a panic stands for the kill) leaves the stage's
        // temporary folder, which the ledger listed before it was made.
        {
            let mut r = Runner::new(&out).unwrap();
            let killed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                let _ = r.stage("epoch-reference", &Inputs::new(), |dir| {
                    std::fs::create_dir_all(dir.join("sub")).unwrap();
                    std::fs::write(dir.join("sub/x.bin"), [0u8; 16]).unwrap();
                    panic!("killed");
                });
            }));
            assert!(killed.is_err());
        }
        let stale: Vec<String> = names(&out)
            .into_iter()
            .filter(|n| n.starts_with(".epoch-reference.part-"))
            .collect();
        assert_eq!(stale.len(), 1, "{:?}", names(&out));
        // A ledger being written when a run was killed.
        std::fs::write(out.join(".stages.part-4242-0-7.json"), "{").unwrap();
        // Names the product did not write, some of them like its temporaries: kept.
        let keep = [
            ".hidden",
            "sources",
            "notes.part-1",
            ".x.part-",
            ".part-12",
            ".epoch-old.part-1",
            ".thesis.part-1-2-3.docx",
            ".epoch-other.part-9-9-9",
        ];
        for k in keep {
            std::fs::create_dir_all(out.join(k)).unwrap();
        }
        let r = Runner::new(&out).unwrap();
        let mut want: Vec<String> = keep.iter().map(|k| k.to_string()).collect();
        want.extend([MARKER.to_string(), "stages.json".into()]);
        want.sort();
        assert_eq!(names(&out), want);
        // A second run on the same folder while the first holds it.
        let e = Runner::new(&out).err().expect("refused");
        assert!(matches!(e, StageError::Busy { .. }), "{e}");
        let e = e.to_string();
        assert!(
            e.contains(&out.display().to_string()) && e.contains("another cloudcontrol run"),
            "{e}"
        );
        drop(r);
        Runner::new(&out).unwrap();
    }
}
