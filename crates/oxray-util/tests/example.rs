//! Runs the `util_scene` example and checks its image: every material shows where the layout
//! says, shadows darken the ground, and the output is identical with 1 and 4 threads.

#[path = "../examples/util_scene.rs"]
mod util_scene;

fn render_with(threads: usize) -> Vec<[u8; 4]> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| util_scene::render(160, 100).map_err(|e| e.to_string()))
        .unwrap()
}

#[test]
fn util_scene_shows_both_material_sets_and_shadows() {
    let a = render_with(1);
    let b = render_with(4);
    assert_eq!(a, b, "output differs between 1 and 4 threads");
    let at = |x: usize, y: usize| a[y * 160 + x];
    // Dominant channel of a pixel.
    let dominant = |p: [u8; 4]| {
        let (r, g, b) = (p[0] as i32, p[1] as i32, p[2] as i32);
        if r > g + 40 && r > b + 40 {
            "red"
        } else if b > r + 40 && b > g + 20 {
            "blue"
        } else if g > r + 40 && g > b + 40 {
            "green"
        } else if r > b + 60 && g > b + 60 {
            "yellow"
        } else {
            "other"
        }
    };
    // Left ball (material set 0): red upper half over blue lower half; right ball (set 1):
    // yellow over green. The balls sit at x = -1.3 and 1.3, seen from z = -6.
    let left_x = 58;
    let right_x = 102;
    assert_eq!(dominant(at(left_x, 60)), "red", "{:?}", at(left_x, 60));
    assert_eq!(dominant(at(left_x, 74)), "blue", "{:?}", at(left_x, 74));
    assert_eq!(dominant(at(right_x, 60)), "yellow", "{:?}", at(right_x, 60));
    assert_eq!(dominant(at(right_x, 74)), "green", "{:?}", at(right_x, 74));
    // The shadow ray type: ground just behind-right of a ball (away from the light) is darker
    // than open ground.
    let luminance = |p: [u8; 4]| p[0] as u32 + p[1] as u32 + p[2] as u32;
    let open = luminance(at(5, 95));
    let shadowed = (60..100)
        .flat_map(|x| (78..90).map(move |y| (x, y)))
        .map(|(x, y)| luminance(at(x, y)))
        .min()
        .unwrap();
    assert!(
        shadowed * 2 < open,
        "no shadow: open {open}, darkest {shadowed}"
    );
}
