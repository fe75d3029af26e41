//! Unit tests of `adjust::datum`.

mod tests {
    use cloudcontrol::adjust::datum::*;
    use nalgebra::Vector3;

    fn p(x: f64, y: f64, z: f64, k: [bool; 3]) -> (Vector3<f64>, [bool; 3]) {
        (Vector3::new(x, y, z), k)
    }

    #[test]
    fn plan_and_height_control_fix_the_datum_only_together() {
        let xy = [true, true, false];
        let z = [false, false, true];
        let all = [true; 3];
        // Four 2-D points: no height.
        // (2-D points at one approximate height: any height spread gives the tilt a weak
        // hold through their plan coordinates.)
        let c = [
            p(0., 0., 6., xy),
            p(500., 0., 6., xy),
            p(0., 400., 6., xy),
            p(500., 400., 6., xy),
        ];
        let e = check_control_geometry(&c).unwrap_err().to_string();
        assert!(e.contains("2-D") && e.contains("heights"), "{e}");
        // Plus three height points not on a line: fixed.
        let mut d = c.to_vec();
        d.extend([
            p(100., 50., 4., z),
            p(400., 60., 8., z),
            p(250., 350., 6., z),
        ]);
        check_control_geometry(&d).unwrap();
        // Height points on a line leave the tilt about it free.
        let mut l = c.to_vec();
        l.extend([
            p(0., 200., 6., z),
            p(250., 200., 6., z),
            p(500., 200., 6., z),
        ]);
        assert!(check_control_geometry(&l).is_err());
        // One 3-D point and 2-D points: the tilt is still free.
        let mut o = c.to_vec();
        o.push(p(250., 200., 6., all));
        assert!(check_control_geometry(&o).is_err());
        // Two 3-D points and a 2-D point off their line fix all seven.
        let t = [
            p(0., 0., 5., all),
            p(500., 0., 5., all),
            p(200., 400., 5., xy),
        ];
        assert!(
            check_control_geometry(&t).is_err(),
            "the tilt about the 3-D points' line needs a height off it"
        );
        let t = [
            p(0., 0., 5., all),
            p(500., 0., 7., all),
            p(200., 400., 3., z),
            p(100., 300., 3., xy),
        ];
        check_control_geometry(&t).unwrap();
        // 3-D control keeps its messages.
        let e = check_control_geometry(&[
            p(0., 0., 0., all),
            p(100., 50., 0., all),
            p(200., 100., 0., all),
        ])
        .unwrap_err()
        .to_string();
        assert!(e.contains("collinear"), "{e}");
    }
}
