use std::sync::Arc;
use std::time::Instant;
use sabre::model::Scene;
use sabre::sim::*;
fn main() {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).unwrap());
    let x0 = scene.default_state();
    println!("nx {} nq {} no {}", scene.nx(), scene.nq(), scene.no());
    let q = &x0[..scene.nq()];
    let g = scene.fk(q, "grasp").unwrap();
    println!("grasp at home {:?}", g.translation.vector);
    let h = scene.object_fk(&[0.0], "handle_frame").unwrap();
    println!("handle {:?}", h.translation.vector);
    let model = RolloutModel::new(scene.clone(), RolloutConfig::default()).unwrap();
    let (n, k) = (40, 66);
    let mut u = vec![0.0; n * k * scene.nq()];
    for i in 0..n { for s in 0..k { for j in 0..scene.nq() { u[(i*k+s)*scene.nq()+j] = 0.3 * (((i*7+j*3+s) % 11) as f64 / 11.0 - 0.5); } } }
    for threads in [1, 2] {
        let _ = model.rollout(&x0, &u, n, k, Some(threads)).unwrap();
        let t = Instant::now();
        let reps = 5;
        for _ in 0..reps { let _ = model.rollout(&x0, &u, n, k, Some(threads)).unwrap(); }
        let dt = t.elapsed().as_secs_f64() / reps as f64;
        println!("threads {threads}: {:.2} ms per batch, {:.0} steps/s", dt*1e3, (n*k) as f64 / dt);
    }
    {
        let mut w = sabre::sim::SimWorld::new(scene.clone(), &sabre::sim::world::WorldConfig{dt:0.015, colliders: sabre::sim::world::RobotColliders::Links(scene.rollout_contact_links.clone()), drive: sabre::sim::world::RobotDrive::KinematicServo{bandwidth:40.0}, contact_friction:0.2, solver_iterations:2}).unwrap();
        let tmpl = w.clone();
        let t = Instant::now();
        for _ in 0..1000 { w.restore_from(&tmpl); }
        println!("restore: {:.2} us", t.elapsed().as_secs_f64()*1e3);
        let t = Instant::now();
        for _ in 0..1000 { w.step(); }
        println!("step: {:.2} us", t.elapsed().as_secs_f64()*1e3);
    }
    let b1 = model.rollout(&x0, &u, n, k, Some(1)).unwrap();
    let b2 = model.rollout(&x0, &u, n, k, Some(2)).unwrap();
    println!("identical: {}", b1 == b2);
    // free motion tracking: constant u on joint 1
    let mut u1 = vec![0.0; k * scene.nq()];
    for s in 0..k { u1[s*scene.nq()+3] = 0.5; u1[s*scene.nq()] = 0.2; }
    let b = model.rollout(&x0, &u1, 1, k, Some(1)).unwrap();
    let nx = scene.nx();
    for s in [1, 5, 10, 30, 66] { println!("step {s}: qd0 {:.4} qd3 {:.4} o {:.4}", b.states[s*nx+10], b.states[s*nx+13], b.states[s*nx+20]); }
}
#[allow(dead_code)]
fn unused() {}
