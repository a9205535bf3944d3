//! lavapipe (Mesa 22.3) silently ends a shader invocation after 65,535 loop iterations.
//! The kernel counts its iterations against `TRAVERSAL_BUDGET`: a scene that needs more
//! must fail loudly, and one that needs nearly as many must still be exact.
//!
//! The scenes are stacks of thin slivers along the diagonal of a square, one per height.
//! Camera rays pass beside every sliver but through every sliver's box on their way to the
//! floor, so closest-hit traversal must test every sliver. (Identical copies of one
//! triangle would do the same, but obvhs builds them into a chain as deep as the copies
//! are many, which the renderer refuses before it traces.)

mod common;
use aorender::{Control, DeviceKind, Error, Scene, Session};
use common::*;

/// `count` thin slivers along the diagonal of the square [-1, 1]², one above the other
/// from z = 0 to z = `height`.
fn slivers(count: usize, height: f32) -> Vec<[[f32; 3]; 3]> {
    (0..count)
        .map(|i| {
            let z = i as f32 / count as f32 * height;
            [[-1.0, -1.0, z], [1.0, 1.0, z], [-0.98, -1.0, z]]
        })
        .collect()
}

/// Renders `scene` on every GPU option and on the CPU, and checks that every pixel is
/// 0.5 (the albedo, no AO ray reaching anything) and that the two agree.
fn assert_every_pixel_is_one_half(scene: &Scene) {
    let cpu = render_on(scene, DeviceKind::Cpu);
    for options in gpu_configs() {
        let film = render_with(scene, &options);
        for v in film.mean() {
            assert_eq!(v as f32, 0.5, "{}: pixel value {v}: a traversal was cut short", label(&options));
        }
        assert_eq!(cpu.mean(), film.mean());
    }
}

fn sliver_stack(count: usize, dir: &std::path::Path) -> Scene {
    let mut tris = slivers(count, 1.0);
    // The floor is a triangle in the same BVH, behind the slivers: a traversal cut short
    // never reaches it and returns the background (0) instead of the floor's 0.5.
    tris.push([[-4.0, -4.0, -2.0], [4.0, -4.0, -2.0], [0.0, 4.0, -2.0]]);
    let obj = dir.join("slivers.obj");
    write_obj(&obj, &tris);
    // The camera looks down at (0.5, -0.5), half a unit from the diagonal; the AO rays
    // from the floor are too short to reach the slivers, so every sample is the albedo.
    let text = r#"
        [image]
        width = 4
        height = 4
        [sampling]
        spp = 2
        max_distance = 0.001
        [camera]
        type = "orthographic"
        eye = [0.5, -0.5, 3.0]
        look_at = [0.5, -0.5, 0.0]
        height = 0.01
        [[object]]
        type = "mesh"
        file = "slivers.obj"
        albedo = 0.5
    "#;
    scene_from_toml(text, dir)
}

#[test]
fn a_traversal_over_budget_is_reported_not_truncated() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    let scene = sliver_stack(80_000, dir.path());
    for options in gpu_configs() {
        let rendered = Session::new(&device(options.device), scene.clone(), &options.bvh)
            .and_then(|session| session.render(&session.default_request())?.complete(&mut Control::default()));
        match rendered {
            Err(e @ Error::TraversalBudget { count, .. }) => {
                assert!(count > 0);
                // One line that names the scene's file and the way out.
                let line = e.to_string();
                assert!(line.starts_with(&format!("{}: ", dir.path().join("test.toml").display())), "{line}");
                assert!(line.ends_with("the CPU reference (`--device cpu`) has no such limit"), "{line}");
            }
            Err(e) => panic!("{}: expected a traversal-budget error, got: {e}", label(&options)),
            Ok(out) => {
                panic!("{}: 80,000 slivers rendered without an error (mean {})", label(&options), out.film.image_mean())
            }
        }
    }
}

#[test]
fn a_traversal_near_the_budget_is_exact() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    // About 40,000 primitive tests plus the inner nodes on the way: well past half of
    // lavapipe's cap, so a kernel that looped more than it counts would be cut short.
    // Every camera ray reaches the floor; no AO ray reaches anything: each sample is 0.5.
    assert_every_pixel_is_one_half(&sliver_stack(40_000, dir.path()));
}

#[test]
fn a_ray_through_a_row_of_instances_stays_within_the_budget() {
    if !gpu_available() {
        return;
    }
    // One mesh of 300 slivers placed 100 times in a row along the view: a ray down the row
    // crosses every instance and every sliver's box in it, about 30,000 steps, though the
    // BVH holds the mesh once. Few pixels see the row and the others only the floor, so
    // passes grow to many samples: the samples an invocation takes must be bounded by the
    // instances a ray can enter, not by the nodes and primitives counted once.
    let dir = temp_dir();
    write_obj(&dir.path().join("slivers.obj"), &slivers(300, 0.01));
    let mut text = r#"
        [image]
        width = 64
        height = 64
        [sampling]
        spp = 16
        max_distance = 0.001
        [camera]
        type = "orthographic"
        eye = [0.0, 0.0, 3.0]
        look_at = [0.0, 0.0, 0.0]
        height = 96.0
        [[object]]
        type = "plane"
        point = [0.0, 0.0, -5.0]
        normal = [0.0, 0.0, 1.0]
        albedo = 0.5
    "#
    .to_string();
    for j in 0..100 {
        text += &format!(
            "[[object]]\ntype = \"mesh\"\nfile = \"slivers.obj\"\nalbedo = 0.5\n\
             transform = {{ translate = [0.0, 0.0, {}] }}\n",
            -0.02 * j as f32
        );
    }
    let scene = scene_from_toml(&text, dir.path());
    assert_eq!(scene.instances.len(), 100);
    // No AO ray reaches anything within 0.001: each sample is the albedo, 0.5.
    assert_every_pixel_is_one_half(&scene);
}
