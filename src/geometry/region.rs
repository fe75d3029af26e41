//! Regions of a raster grid grown through 4-neighbours: the one flood fill of the crate
//! (speckles of a disparity map, changed areas of a DEM of difference).

/// Grows the 4-connected region of cell `start` (row-major, `width` columns, `height`
/// rows): a neighbour `q` of a member `p` joins when `joins(p, q)` says so, and `joins`
/// must mark it (so that it joins once). The members, `start` first, end in `region`
/// (cleared first); `stack` is scratch kept between calls.
pub fn grow_region(
    (width, height): (usize, usize),
    start: usize,
    region: &mut Vec<usize>,
    stack: &mut Vec<usize>,
    mut joins: impl FnMut(usize, usize) -> bool,
) {
    region.clear();
    stack.clear();
    stack.push(start);
    while let Some(p) = stack.pop() {
        region.push(p);
        let (x, y) = (p % width, p / width);
        for (ok, q) in [
            (x > 0, p.wrapping_sub(1)),
            (x + 1 < width, p + 1),
            (y > 0, p.wrapping_sub(width)),
            (y + 1 < height, p + width),
        ] {
            if ok && joins(p, q) {
                stack.push(q);
            }
        }
    }
}
