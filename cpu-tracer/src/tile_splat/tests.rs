use super::*;

/// A kernel with no centres (the small path reads a sphere's hits from `centres`).
fn kernel<'a>(centres: &'a [[f32; 4]], ties: Ties<'a>) -> Kernel<'a, wide::f32x8> {
    let z = <wide::f32x8 as Arith>::splat(0.0);
    Kernel { ties, centres, o: [0.0; 3], lane: z, lane4: z, row2: z, tx1: 63, ty1: 63, cull: false, wide: false }
}

#[test]
fn small_spheres_keep_the_nearer_hit_and_the_tie_rule() {
    let tile = Tile { x0: 0, y0: 0, w: TILE, h: TILE };
    let mut buf = TileBuf::new();
    // Sphere 9 first: hits at 2.0 on (10, 5) and 3.0 on (11, 6); none on the other two.
    let (inf, no) = (f32::INFINITY, f32::NAN);
    let mut centres = vec![[0.0; 4]; 10];
    centres[9] = [2.0, no, no, 3.0];
    // Sphere 3: the same distance on (10, 5) (a tie: the smaller index wins), nearer on
    // (11, 5), farther on (11, 6).
    centres[3] = [2.0, 1.0, no, 4.0];
    let r = Rect { x0: 10, y0: 5, x1: 11, y1: 6 };
    let k = kernel(&centres, Ties::Index);
    splat_small(&k, &tile, r, 9, &mut buf);
    splat_small(&k, &tile, r, 3, &mut buf);
    let at = |x: usize, y: usize| (buf.depth[y * TILE + x], buf.ids[y * TILE + x]);
    assert_eq!(at(10, 5), (2.0, 3));
    assert_eq!(at(11, 5), (1.0, 3));
    assert_eq!(at(10, 6), (inf, NO_HIT));
    assert_eq!(at(11, 6), (3.0, 9));
    // A window past a 12×7 tile's right and bottom edges, hitting all four pixels,
    // writes only its pixel inside the tile, (11, 6).
    let tile = Tile { x0: 0, y0: 0, w: 12, h: 7 };
    let centres = [[1.0f32; 4]; 10];
    let k = Kernel { tx1: 11, ty1: 6, ..kernel(&centres, Ties::Index) };
    let mut buf = TileBuf::new();
    splat_small(&k, &tile, Rect { x0: 11, y0: 6, x1: 12, y1: 7 }, 9, &mut buf);
    let written: Vec<usize> = (0..KEYS).filter(|&p| buf.ids[p] != NO_HIT).collect();
    assert_eq!(written, vec![6 * TILE + 11]);
}
