//! Rapier's f32 build against its f64 build on the rollout model's in-contact work (whether f32
//! would speed up the contact step; not part of sabre's build): the proxies' placements along eight
//! in-contact rollouts replayed through Rapier's whole pipeline in each, the object the shelf's door
//! as a multibody.
//!
//!     cargo run --release --manifest-path benches/rapier_f32/Cargo.toml
//!     cargo run --release --manifest-path benches/rapier_f32/Cargo.toml --features simd8
//!
//! Prints the median time of a pipeline step in each build over alternating rounds, the largest
//! difference of the door's angle between them, and the f64 build's step with the carcass's
//! colliders left out (collision groups that let only the door and its handle be touched).
use std::time::Instant;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use sabre::model::kinematics::Shape as Primitive;
use sabre::model::Scene;

struct Step {
    poses: [Isometry3<f64>; 2],
    twists: [(Vector3<f64>, Vector3<f64>); 2],
    o: f64,
    reset: bool,
}

/// The proxies' placements (pose and twist of panda_link5 and panda_link7 at each step) along eight
/// rollouts of sabre's reduced model of the criterion bench's in-contact batch (the hook on the
/// shelf handle, pulling; benches/data/shelf_hooked.json with seeded noise).
fn trace(scene: &std::sync::Arc<Scene>) -> Vec<Step> {
    use rand::{Rng, SeedableRng};
    let data: serde_json::Value =
        serde_json::from_str(include_str!("../../data/shelf_hooked.json")).expect("benches/data/shelf_hooked.json");
    let floats = |v: &serde_json::Value| v.as_array().unwrap().iter().map(|e| e.as_f64().unwrap()).collect::<Vec<_>>();
    let x0 = floats(&data["x0"]);
    let nominal: Vec<f64> = data["U"].as_array().unwrap().iter().flat_map(floats).collect();
    let (nq, n) = (scene.nq(), 8);
    let k = nominal.len() / nq;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let u: Vec<f64> = (0..n)
        .flat_map(|_| nominal.iter().map(|&v| v + rng.random_range(-0.02..0.02)).collect::<Vec<_>>())
        .collect();
    let model = sabre::sim::RolloutModel::new(scene.clone(), sabre::sim::RolloutConfig::default()).unwrap();
    let batch = model.rollout(&x0, &u, n, k, Some(1)).unwrap();
    let nx = scene.nx();
    let links = ["panda_link5", "panda_link7"].map(|l| scene.robot.link_id(l).unwrap());
    let mut out = Vec::new();
    for i in 0..n {
        for step in 0..k {
            let x = &batch.states[(i * (k + 1) + step) * nx..(i * (k + 1) + step + 1) * nx];
            let next = &batch.states[(i * (k + 1) + step + 1) * nx..(i * (k + 1) + step + 2) * nx];
            let (q, qd) = (&x[..nq], &next[nq..2 * nq]);
            let poses = scene.robot.link_poses(&Isometry3::identity(), q);
            let twist = |link: usize| {
                let j = scene.robot.frame_jacobian(&Isometry3::identity(), q, link);
                let t = j * nalgebra::DVector::from_column_slice(qd);
                (Vector3::new(t[0], t[1], t[2]), Vector3::new(t[3], t[4], t[5]))
            };
            out.push(Step {
                poses: links.map(|l| poses[l]),
                twists: links.map(twist),
                o: x[2 * nq],
                reset: step == 0,
            });
        }
    }
    out
}

macro_rules! engine {
    ($name:ident, $r:ident) => {
        mod $name {
            use super::*;
            use $r::prelude::*;
            type R = Real;

            fn iso(i: &Isometry3<f64>) -> Pose {
                let t = i.translation.vector;
                let q = i.rotation;
                Pose::from_parts(
                    Vector::new(t.x as R, t.y as R, t.z as R),
                    Rotation::from_xyzw(q.i as R, q.j as R, q.k as R, q.w as R),
                )
            }
            fn shape(s: &Primitive) -> (ColliderBuilder, Isometry3<f64>) {
                match *s {
                    Primitive::Box { half_extents: h } => (
                        ColliderBuilder::cuboid(h.x as R, h.y as R, h.z as R),
                        Isometry3::identity(),
                    ),
                    Primitive::Sphere { radius } => (ColliderBuilder::ball(radius as R), Isometry3::identity()),
                    Primitive::Cylinder { radius, half_length } => (
                        ColliderBuilder::cylinder(half_length as R, radius as R),
                        Isometry3::rotation(nalgebra::Vector3::x() * std::f64::consts::FRAC_PI_2),
                    ),
                    Primitive::Capsule { radius, half_length } => (
                        ColliderBuilder::capsule_z(half_length as R, radius as R),
                        Isometry3::identity(),
                    ),
                    Primitive::Hull { ref points, .. } => {
                        let v: Vec<Vector> = points
                            .iter()
                            .map(|p| Vector::new(p.x as R, p.y as R, p.z as R))
                            .collect();
                        (ColliderBuilder::convex_hull(&v).unwrap(), Isometry3::identity())
                    }
                }
            }

            /// Attaches a link's collision shapes, placed at `rel` in the body's frame, to `body` as
            /// massless colliders (the body's mass is set on it).
            fn attach(
                colliders: &mut ColliderSet,
                bodies: &mut RigidBodySet,
                body: RigidBodyHandle,
                rel: &Isometry3<f64>,
                link: &sabre::model::kinematics::Link,
                group: InteractionGroups,
            ) {
                for c in &link.collisions {
                    let (b, frame) = shape(&c.shape);
                    colliders.insert_with_parent(
                        b.position(iso(&(rel * c.origin * frame)))
                            .density(0.0)
                            .friction(0.2)
                            .collision_groups(group)
                            .build(),
                        body,
                        bodies,
                    );
                }
            }

            #[derive(Clone)]
            pub struct World {
                bodies: RigidBodySet,
                colliders: ColliderSet,
                mbs: MultibodyJointSet,
                impulse: ImpulseJointSet,
                islands: IslandManager,
                bp: BroadPhaseBvh,
                np: NarrowPhase,
                ccd: CCDSolver,
                soft: SoftBodySet,
                proxies: [RigidBodyHandle; 2],
                door: MultibodyJointHandle,
            }

            pub fn build(scene: &Scene, carcass_colliders: bool) -> World {
                let mut bodies = RigidBodySet::new();
                let mut colliders = ColliderSet::new();
                let mut mbs = MultibodyJointSet::new();
                let robot_group = InteractionGroups::new(Group::GROUP_1, Group::GROUP_2, InteractionTestMode::And);
                let object_group = InteractionGroups::new(Group::GROUP_2, Group::GROUP_1, InteractionTestMode::And);
                // Proxies: link5 and link7 (hand and hook_finger fixed to it), 1.5 kg each.
                let q0 = &scene.default_state()[..scene.nq()];
                let poses = scene.robot.link_poses(&Isometry3::identity(), q0);
                let mut proxies = Vec::new();
                for (root, members) in [
                    ("panda_link5", vec!["panda_link5"]),
                    ("panda_link7", vec!["panda_hand", "hook_finger"]),
                ] {
                    let rl = scene.robot.link_id(root).unwrap();
                    let rb = bodies.insert(
                        RigidBodyBuilder::dynamic()
                            .additional_mass_properties(MassProperties::new(Vector::ZERO, 1.5, Vector::splat(0.01)))
                            .gravity_scale(0.0)
                            .can_sleep(false)
                            .build(),
                    );
                    for m in members {
                        let l = scene.robot.link_id(m).unwrap();
                        let rel = poses[rl].inverse() * poses[l];
                        attach(&mut colliders, &mut bodies, rb, &rel, &scene.robot.links[l], robot_group);
                    }
                    proxies.push(rb);
                }
                // Object: the carcass fixed, the door (with the handle) on its revolute joint.
                let opose = scene.object_pose;
                let ob = scene.object.link_poses(&opose, &[0.0]);
                let cab = scene.object.link_id("cabinet").unwrap();
                let door = scene.object.link_id("door").unwrap();
                let carcass = bodies.insert(RigidBodyBuilder::fixed().pose(iso(&ob[cab])).build());
                for c in scene.object.links[cab].collisions.iter().filter(|_| carcass_colliders) {
                    let (b, frame) = shape(&c.shape);
                    colliders.insert_with_parent(
                        b.position(iso(&(c.origin * frame)))
                            .friction(0.2)
                            .collision_groups(object_group)
                            .build(),
                        carcass,
                        &mut bodies,
                    );
                }
                let door_body = bodies.insert(
                    RigidBodyBuilder::dynamic()
                        .pose(iso(&ob[door]))
                        .additional_mass_properties(MassProperties::new(
                            Vector::new(0.008, -0.1475, 0.0),
                            5.9,
                            Vector::new(0.43, 0.39, 0.042),
                        ))
                        .can_sleep(false)
                        .build(),
                );
                for name in ["door", "handle"] {
                    let l = scene.object.link_id(name).unwrap();
                    let rel = ob[door].inverse() * ob[l];
                    attach(&mut colliders, &mut bodies, door_body, &rel, &scene.object.links[l], object_group);
                }
                let joint = scene.object.joints.iter().find(|j| j.name == "articulation").unwrap();
                let align = UnitQuaternion::rotation_between(&nalgebra::Vector3::x(), &joint.axis)
                    .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), std::f64::consts::PI));
                let f1 = joint.origin * Isometry3::from_parts(Default::default(), align);
                let f2 = Isometry3::from_parts(Default::default(), align);
                let j = GenericJointBuilder::new(JointAxesMask::LOCKED_REVOLUTE_AXES)
                    .local_frame1(iso(&f1))
                    .local_frame2(iso(&f2))
                    .limits(JointAxis::AngX, [0.0, 1.57])
                    .contacts_enabled(false)
                    .build();
                let door_joint = mbs.insert(carcass, door_body, j, true).unwrap();
                {
                    let (mb, _) = mbs.get_mut(door_joint).unwrap();
                    mb.forward_kinematics(&bodies, true);
                    mb.damping_mut().fill(2.0);
                    mb.frictions_mut().fill(4.0);
                }
                World {
                    bodies,
                    colliders,
                    mbs,
                    impulse: ImpulseJointSet::new(),
                    islands: IslandManager::new(),
                    bp: BroadPhaseBvh::new(),
                    np: NarrowPhase::new(),
                    ccd: CCDSolver::new(),
                    soft: SoftBodySet::new(),
                    proxies: [proxies[0], proxies[1]],
                    door: door_joint,
                }
            }

            pub fn run(template: &World, trace: &[Step]) -> (f64, Vec<f64>) {
                let mut params = IntegrationParameters {
                    dt: 0.015,
                    num_solver_iterations: 1,
                    contact_recycling: false,
                    ..IntegrationParameters::default()
                };
                params.contact_softness.natural_frequency = 60.0;
                params.contact_softness.damping_ratio = 1.0;
                params.normalized_prediction_distance = 0.01;
                let mut pipeline = PhysicsPipeline::new();
                let mut w = template.clone();
                let mut seconds = 0.0;
                let mut opening = Vec::new();
                for s in trace {
                    if s.reset {
                        w = template.clone();
                        let (mb, _) = w.mbs.get_mut(w.door).unwrap();
                        let cur = mb.link(1).map(|l| l.joint().coords()[3]).unwrap_or(0.0);
                        let mut disp = vec![0.0 as R; mb.ndofs()];
                        disp[0] = s.o as R - cur;
                        mb.apply_displacements(&disp);
                        mb.forward_kinematics(&w.bodies, false);
                        mb.update_rigid_bodies(&mut w.bodies, true);
                    }
                    for i in 0..2 {
                        let rb = &mut w.bodies[w.proxies[i]];
                        rb.set_position(iso(&s.poses[i]), true);
                        let (v, om) = s.twists[i];
                        rb.set_linvel(Vector::new(v.x as R, v.y as R, v.z as R), true);
                        rb.set_angvel(Vector::new(om.x as R, om.y as R, om.z as R), true);
                    }
                    let t = Instant::now();
                    pipeline.step(
                        Vector::new(0.0, 0.0, -9.81),
                        &params,
                        &mut w.islands,
                        &mut w.bp,
                        &mut w.np,
                        &mut w.bodies,
                        &mut w.colliders,
                        &mut w.impulse,
                        &mut w.mbs,
                        &mut w.soft,
                        &mut w.ccd,
                        &(),
                        &(),
                    );
                    seconds += t.elapsed().as_secs_f64();
                    let (mb, _) = w.mbs.get(w.door).unwrap();
                    opening.push(mb.link(1).map(|l| l.joint().coords()[3] as f64).unwrap_or(0.0));
                }
                (seconds, opening)
            }
        }
    };
}

engine!(f64_engine, rapier3d_f64);
engine!(f32_engine, rapier3d);

fn main() {
    let scene = std::sync::Arc::new(Scene::load("royalpanda", "shelf", None).unwrap());
    let trace = trace(&scene);
    let a = f64_engine::build(&scene, true);
    let b = f32_engine::build(&scene, true);
    // The carcass's colliders left out: only the door and its handle can be touched.
    let c = f64_engine::build(&scene, false);
    let rounds = 15;
    let (mut ta, mut tb, mut tc) = (Vec::new(), Vec::new(), Vec::new());
    let (mut oa, mut ob) = (Vec::new(), Vec::new());
    for r in 0..rounds {
        // Alternate the order so that neither build always runs first.
        let order: [u8; 3] = if r % 2 == 0 { [0, 1, 2] } else { [2, 1, 0] };
        for which in order {
            match which {
                0 => {
                    let (s, o) = f64_engine::run(&a, &trace);
                    ta.push(s);
                    oa = o;
                }
                1 => {
                    let (s, o) = f32_engine::run(&b, &trace);
                    tb.push(s);
                    ob = o;
                }
                _ => tc.push(f64_engine::run(&c, &trace).0),
            }
        }
    }
    for t in [&mut ta, &mut tb, &mut tc] {
        t.sort_by(f64::total_cmp);
    }
    let n = trace.len() as f64;
    let median = |t: &[f64]| 1e6 * t[rounds / 2] / n;
    let dev = oa.iter().zip(&ob).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    let moved = oa.iter().zip(&trace).map(|(x, s)| (x - s.o).abs()).fold(0.0, f64::max);
    println!(
        "pipeline step, median over {rounds} alternating rounds: f64 {:.2} µs, f32 {:.2} µs ({:.2}× f64's time), \
         f64 without the carcass colliders {:.2} µs ({:.2}×); door angle f64 vs f32: largest difference {:.1e} rad \
         (largest door motion over a step {:.3} rad)",
        median(&ta),
        median(&tb),
        tb[rounds / 2] / ta[rounds / 2],
        median(&tc),
        tc[rounds / 2] / ta[rounds / 2],
        dev,
        moved
    );
}
