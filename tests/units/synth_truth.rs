//! Unit tests of `synth::truth`.

mod tests {
    use cloudcontrol::synth::truth::*;
    use nalgebra::Matrix3;
    use nalgebra::Vector2;

    #[test]
    fn truth_files_as_documented() {
        let d = tempfile::tempdir().unwrap();
        let eo = d.path().join("eo.csv");
        // Written by hand from formats/synth/README.md (truth/epochs/<epoch>/eo.csv).
        std::fs::write(
            &eo,
            "photo,strip,index,x,y,z,omega_deg,phi_deg,kappa_deg,r11,r12,r13,r21,r22,r23,r31,r32,r33\n\
             film_s01_001,1,1,500010.5,4400020.25,3050,0,0,180,-1,0,0,0,1,0,0,0,-1\n",
        )
        .unwrap();
        let v = read_truth_eo(&eo).unwrap();
        assert_eq!(v.len(), 1);
        assert_eq!(v[0].0, "film_s01_001");
        assert_eq!(
            v[0].1,
            Matrix3::new(-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0)
        );
        assert_eq!(v[0].2, [500010.5, 4400020.25, 3050.0]);
        std::fs::write(
            &eo,
            "photo,x,y,z,r11,r12,r13,r21,r22,r23,r31,r32\na,1,2,3,1,0,0,0,1,0,0,0\n",
        )
        .unwrap();
        assert!(read_truth_eo(&eo)
            .unwrap_err()
            .to_string()
            .contains("line 1: no column \"r33\""));

        let af = d.path().join("scan_affine.csv");
        std::fs::write(
            &af,
            "# x_mm = a11·col + a12·row + a13, y_mm = a21·col + a22·row + a23\n\
             photo,a11,a12,a13,a21,a22,a23\n\
             film_s01_001,0.1,0.0,-120,0.0,-0.1,120\n",
        )
        .unwrap();
        let m = read_scan_affine(&af).unwrap();
        let mm = m["film_s01_001"].pixel_to_mm(Vector2::new(1200.0, 1200.0));
        assert!(mm.norm() < 1e-12, "{mm:?}");
        std::fs::write(&af, "photo,a11,a12,a13,a21,a22,a23\nf,0.1,0,x,0,-0.1,0\n").unwrap();
        assert!(read_scan_affine(&af)
            .unwrap_err()
            .to_string()
            .contains("line 2, column a13: \"x\" is not a number"));
    }
}
