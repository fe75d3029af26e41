//! Unit tests of the fusion of pairs' points into a DSM: median, count and spread per
//! cell against values worked by hand; holes stay nodata; the grid's alignment and
//! bounds.

mod tests {
    use cloudcontrol::dense::fusion::{DsmGrid, Fusion};
    use cloudcontrol::geometry::Lattice;

    /// The grid of `cell` over `area` on a 1 m lattice whose corner is the area's, outward
    /// to whole metres.
    fn covering(
        area: [f64; 4],
        cell: f64,
    ) -> Result<DsmGrid, cloudcontrol::geometry::GeometryError> {
        Lattice {
            base_m: 1.0,
            corner: [area[0].floor(), area[3].ceil()],
        }
        .grid(cell, area)
    }

    #[test]
    fn cells_take_the_median_count_and_spread_of_their_points() {
        let grid = covering([10.2, 20.0, 13.9, 22.0], 1.0).unwrap();
        // From the lattice's corner: x from 10, y down from 22; 4 × 2 cells.
        assert_eq!(
            (grid.x_min, grid.y_max, grid.width, grid.height),
            (10.0, 22.0, 4, 2)
        );
        let mut f = Fusion::new(grid);
        // Cell (0, 0): 1, 2, 3, 100 → median 2.5; deviations 1.5, 0.5, 0.5, 97.5 → MAD 1.
        f.extend([
            [10.5, 21.5, 1.0],
            [10.1, 21.9, 100.0],
            [10.9, 21.1, 3.0],
            [10.5, 21.5, 2.0],
        ]);
        // Cell (3, 1): one point; outside and NaN are dropped.
        f.extend([[13.5, 20.5, 7.0], [14.5, 20.5, 9.0], [10.5, 21.5, f64::NAN]]);
        assert_eq!(f.len(), 5);
        let s = f.finish(1).unwrap();
        assert_eq!(s.dsm.data[0], 2.5);
        assert_eq!(s.count.data[0], 4.0);
        assert!((s.spread.data[0] - 1.4826).abs() < 1e-6);
        assert_eq!(s.dsm.data[7], 7.0);
        assert_eq!(s.count.data[7], 1.0);
        assert!(s.spread.data[7].is_nan());
        // Cells without a point stay without data.
        assert!(s.dsm.data[1..7].iter().all(|v| v.is_nan()));
        assert!(s.count.data[1..7].iter().all(|v| v.is_nan()));
    }

    #[test]
    fn a_least_count_leaves_thin_cells_empty() {
        let grid = covering([0.0, 0.0, 2.0, 1.0], 1.0).unwrap();
        let mut f = Fusion::new(grid);
        f.extend([[0.5, 0.5, 1.0], [0.5, 0.5, 2.0], [1.5, 0.5, 5.0]]);
        let s = f.finish(2).unwrap();
        assert_eq!(s.dsm.data[0], 1.5);
        assert!(s.dsm.data[1].is_nan());
    }

    #[test]
    fn impossible_grids_are_refused() {
        for (area, cell) in [
            ([0.0, 0.0, 1.0, 1.0], 0.0),
            ([0.0, 0.0, 1.0, 1.0], f64::NAN),
            ([1.0, 0.0, 0.0, 1.0], 1.0),
            ([0.0, 0.0, 1e6, 1e6], 1e-2),
        ] {
            assert!(covering(area, cell).is_err(), "{area:?} {cell}");
        }
    }
}
