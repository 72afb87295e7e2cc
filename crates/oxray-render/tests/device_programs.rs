use glam::Vec3;
use oxray_render::device::render_on;
use oxray_render::lights::Environment;
use oxray_render::{render, RenderOptions};

#[test]
fn smoke() {
    let opts = RenderOptions {
        width: 32,
        height: 32,
        spp: 4,
        max_depth: 6,
        camera: None,
    };
    let scene = oxray_scene::cornell_box();
    let env = Environment::uniform(Vec3::ZERO);
    let t = std::time::Instant::now();
    let a = render(&scene, &env, &opts, |_| {}).unwrap();
    println!("rust {:?}", t.elapsed());
    let t = std::time::Instant::now();
    let b = render_on(&oxray::Device::cpu(), &scene, &env, &opts, |_| {}).unwrap();
    println!("cxx {:?}", t.elapsed());
    let mut same = 0;
    let mut ma = [0.0f64; 3];
    let mut mb = [0.0f64; 3];
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        if p == q {
            same += 1;
        }
        for c in 0..3 {
            ma[c] += p[c] as f64;
            mb[c] += q[c] as f64;
        }
    }
    println!("same {same} of {}; {ma:?} {mb:?}", a.pixels.len());
}
