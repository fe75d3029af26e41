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
            std::fs::read_dir(&out).unwrap().count(),
            2,
            "one/ and stages.json only"
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

    #[test]
    fn leftovers_of_a_killed_run_are_removed_and_a_busy_folder_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("out");
        let stale = out.join(".epoch-reference.part-999999");
        std::fs::create_dir_all(stale.join("sub")).unwrap();
        std::fs::write(stale.join("sub/x.bin"), [0u8; 16]).unwrap();
        std::fs::write(out.join(".stages.part-4242.json"), "{").unwrap();
        let keep = [".hidden", "sources", "notes.part-1", ".x.part-", ".part-12"];
        for k in keep {
            std::fs::create_dir_all(out.join(k)).unwrap();
        }
        let r = Runner::new(&out).unwrap();
        let mut left: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        let mut want: Vec<String> = keep.iter().map(|k| k.to_string()).collect();
        want.sort();
        assert_eq!(left, want);
        // A second run on the same folder while the first holds it.
        let e = Runner::new(&out).err().expect("refused").to_string();
        assert!(
            e.contains(&out.display().to_string()) && e.contains("another cloudcontrol run"),
            "{e}"
        );
        drop(r);
        Runner::new(&out).unwrap();
    }
}
