//! The built-in Cornell box at low sample counts: checked by image statistics.

#[test]
fn cornell_box_has_a_bright_light_red_and_green_walls_and_no_nan() {
    let (w, h) = (64u32, 64u32);
    let px = oxray_cli::render::render_cornell(w, h, 8, 6).unwrap();
    assert!(
        px.iter().flatten().all(|c| c.is_finite() && *c >= 0.0),
        "NaN, inf or negative radiance"
    );
    let at = |x: u32, y: u32| px[(y * w + x) as usize];
    // The light is at the top centre: the brightest pixel there sees it directly.
    let light = (5..11)
        .flat_map(|y| (26..38).map(move |x| (x, y)))
        .map(|(x, y)| at(x, y))
        .max_by(|a, b| a[0].total_cmp(&b[0]))
        .unwrap();
    assert!(light[0] > 5.0 && light[1] > 3.0, "light {light:?}");
    // Green wall on the left, red on the right (seen from the camera), at mid height: average a
    // small patch to smooth the noise.
    let patch = |x0: u32| {
        let mut s = [0.0f32; 3];
        for y in 28..36 {
            for x in x0..x0 + 4 {
                let p = at(x, y);
                for c in 0..3 {
                    s[c] += p[c];
                }
            }
        }
        s
    };
    let left = patch(2);
    let right = patch(w - 6);
    assert!(
        left[1] > 1.5 * left[0] && left[1] > 1.5 * left[2],
        "left wall not green: {left:?}"
    );
    assert!(
        right[0] > 2.0 * right[1] && right[0] > 2.0 * right[2],
        "right wall not red: {right:?}"
    );
}

#[test]
fn render_is_deterministic_across_thread_counts() {
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| oxray_cli::render::render_cornell(32, 32, 4, 4).map_err(|e| e.to_string()))
            .unwrap()
    };
    let (a, b) = (run(1), run(4));
    assert!(a
        .iter()
        .zip(&b)
        .all(|(p, q)| p.iter().zip(q).all(|(x, y)| x.to_bits() == y.to_bits())));
}
