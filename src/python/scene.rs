//! `_core.Scene`: the robot, the object and its pose; kinematics and dynamics queries on them.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::convert::{array, pose_array, poses_array, view};
use super::error::run;
use super::robot::{parsed, roles_row, visual_rows, RobotOptions, RolesRow, VisualRow};
use crate::model::handle_frame::{handle_frame, infer_handle_frame};
use crate::model::inertials::DEFAULT_DENSITY;
use crate::model::scene::Scene;

/// A self-collision sphere: (name, link, centre xyz in the link frame, radius).
type SphereRow = (String, String, [f64; 3], f64);
/// A collision primitive: (link, kind, size, pose row-major, hull vertices).
type CollisionRow = (String, String, Vec<f64>, Vec<f64>, Vec<[f64; 3]>);

/// The collision primitives of every link of `tree` (see `PyScene::object_collisions`).
fn collision_rows(tree: &crate::model::KinematicTree) -> Vec<CollisionRow> {
    use crate::model::kinematics::Shape;
    let mut out = Vec::new();
    for link in &tree.links {
        for c in &link.collisions {
            let (kind, size) = match &c.shape {
                Shape::Box { half_extents } => ("box", vec![half_extents.x, half_extents.y, half_extents.z]),
                Shape::Sphere { radius } => ("sphere", vec![*radius]),
                Shape::Cylinder { radius, half_length } => ("cylinder", vec![*radius, *half_length]),
                Shape::Capsule { radius, half_length } => ("capsule", vec![*radius, *half_length]),
                Shape::Hull { half_extents, .. } => ("mesh", vec![half_extents.x, half_extents.y, half_extents.z]),
            };
            let m = c.origin.to_homogeneous();
            let pose = (0..4).flat_map(|r| (0..4).map(move |col| m[(r, col)])).collect();
            let points = match &c.shape {
                Shape::Hull { points, .. } => points.iter().map(|p| [p.x, p.y, p.z]).collect(),
                _ => Vec::new(),
            };
            out.push((link.name.clone(), kind.to_string(), size, pose, points));
        }
    }
    out
}

/// A float64 array handed to Python.
type Array<'py> = Bound<'py, PyArrayDyn<f64>>;

/// The URDF text of a built-in asset compiled into the library (`kind`: "robot" or "object").
#[pyfunction]
pub fn builtin_urdf(kind: &str, name: &str) -> PyResult<&'static str> {
    run(|| crate::model::scene::builtin_urdf(kind, name))
}

/// One assumed inertial as Python sees it: (link, mass, centre of mass (3), inertia row-major (9), source).
type AssumedInertialRow = (String, f64, [f64; 3], Vec<f64>, String);
#[pyclass(name = "Scene", module = "sabre._core", frozen)]
pub struct PyScene {
    pub(crate) inner: Arc<Scene>,
}

impl PyScene {
    fn wrap(scene: Scene) -> Self {
        Self { inner: Arc::new(scene) }
    }

    /// (name, link, centre xyz, radius) of one collision sphere.
    fn sphere_row(&self, sp: &crate::model::scene::Sphere) -> SphereRow {
        let link = self.inner.robot.links[sp.link].name.clone();
        (sp.name.clone(), link, [sp.center.x, sp.center.y, sp.center.z], sp.radius)
    }
}

#[pymethods]
impl PyScene {
    /// A built-in robot and object by name; `obj_pose` (x, y, z, roll, pitch, yaw) places the object.
    #[staticmethod]
    #[pyo3(signature = (robot, obj, obj_pose=None))]
    fn load(robot: &str, obj: &str, obj_pose: Option<Vec<f64>>) -> PyResult<Self> {
        run(|| Scene::load(robot, obj, obj_pose.as_deref())).map(Self::wrap)
    }

    /// `joint` keeps one movable object joint, or `handle` the one that moves that link; the others
    /// are fixed at `hold` (default 0 within limits). Moving object links without a complete
    /// inertial get one from their collision geometry at `density` (kg/m³).
    #[staticmethod]
    #[pyo3(signature = (robot_path, obj_path, obj_pose=None, joint=None, hold=None, handle=None, density=DEFAULT_DENSITY))]
    fn from_urdf(
        robot_path: PathBuf,
        obj_path: PathBuf,
        obj_pose: Option<Vec<f64>>,
        joint: Option<String>,
        hold: Option<Vec<(String, f64)>>,
        handle: Option<String>,
        density: f64,
    ) -> PyResult<Self> {
        run(|| {
            Scene::from_urdf_files(&robot_path, &obj_path, obj_pose.as_deref())?
                .with_object_joint(joint.as_deref(), &hold.unwrap_or_default(), handle.as_deref())?
                .with_density(density)
        })
        .map(Self::wrap)
    }

    /// A scene from a robot and an object, each given as (kind, value): ("builtin", name), ("file",
    /// path) or ("text", URDF); `robot` holds the robot's options (tool, held joints, base, postures)
    /// over what its `<sabre>` block declares. A built-in object without `obj_pose` stands at its
    /// default place; `joint`, `hold`, `handle` and `density` as in `from_urdf`.
    #[staticmethod]
    #[pyo3(signature = (robot_source, obj_source, robot, obj_pose=None, joint=None, hold=None, handle=None, density=DEFAULT_DENSITY))]
    #[allow(clippy::too_many_arguments)]
    fn build(
        robot_source: (String, String),
        obj_source: (String, String),
        robot: RobotOptions,
        obj_pose: Option<Vec<f64>>,
        joint: Option<String>,
        hold: Option<Vec<(String, f64)>>,
        handle: Option<String>,
        density: f64,
    ) -> PyResult<Self> {
        run(|| {
            let parsed_robot = parsed(&robot_source.0, &robot_source.1, true)?;
            let parsed_object = parsed(&obj_source.0, &obj_source.1, false)?;
            let default_pose = crate::model::scene::default_object_pose(&obj_source.1);
            let pose = obj_pose
                .as_deref()
                .or((obj_source.0 == "builtin").then_some(&default_pose[..]));
            Scene::from_parts(parsed_robot, parsed_object, pose, &robot.decls()?)?
                .with_object_joint(joint.as_deref(), &hold.unwrap_or_default(), handle.as_deref())?
                .with_density(density)
        })
        .map(Self::wrap)
    }

    #[staticmethod]
    #[pyo3(signature = (robot_urdf, obj_urdf, obj_pose=None, joint=None, hold=None, handle=None, density=DEFAULT_DENSITY))]
    fn from_urdf_strings(
        robot_urdf: &str,
        obj_urdf: &str,
        obj_pose: Option<Vec<f64>>,
        joint: Option<String>,
        hold: Option<Vec<(String, f64)>>,
        handle: Option<String>,
        density: f64,
    ) -> PyResult<Self> {
        run(|| {
            Scene::from_urdf_strings(robot_urdf, obj_urdf, obj_pose.as_deref())?
                .with_object_joint(joint.as_deref(), &hold.unwrap_or_default(), handle.as_deref())?
                .with_density(density)
        })
        .map(Self::wrap)
    }

    /// Density (kg/m³) that moving object links without an inertial were given.
    #[getter]
    fn density(&self) -> f64 {
        self.inner.density
    }

    /// The inertials filled in from collision geometry as (link, mass, centre of mass in the link
    /// frame, inertia about it as a row-major 3 × 3, source).
    fn assumed_inertials(&self) -> Vec<AssumedInertialRow> {
        self.inner
            .assumed_inertials
            .iter()
            .map(|a| {
                let inertia = (0..3).flat_map(|r| (0..3).map(move |c| a.inertia[(r, c)])).collect();
                (a.link.clone(), a.mass, [a.com.x, a.com.y, a.com.z], inertia, a.source.clone())
            })
            .collect()
    }

    /// The movable object joints that move the object frame `frame`, root first.
    fn object_joints_moving(&self, frame: &str) -> PyResult<Vec<String>> {
        run(|| self.inner.object_joints_moving(frame))
    }

    /// (object frame, (4, 4) offset) whose composition is the handle frame named by `handle`: the
    /// frame itself when it has no collision geometry, else the frame inferred from it.
    fn handle_frame<'py>(&self, py: Python<'py>, handle: &str) -> PyResult<(String, Array<'py>)> {
        let found = run(|| handle_frame(&self.inner, handle))?;
        let name = self.inner.object.links[found.link].name.clone();
        Ok((name, pose_array(py, &found.offset)?))
    }

    /// (4, 4) the handle frame inferred from the collision geometry of object link `link`, in that
    /// link's frame.
    fn infer_handle_frame<'py>(&self, py: Python<'py>, link: &str) -> PyResult<Array<'py>> {
        pose_array(py, &run(|| infer_handle_frame(&self.inner, link))?)
    }

    #[getter]
    fn nq(&self) -> usize {
        self.inner.nq()
    }
    #[getter]
    fn no(&self) -> usize {
        self.inner.no()
    }
    #[getter]
    fn nx(&self) -> usize {
        self.inner.nx()
    }
    #[getter]
    fn nu(&self) -> usize {
        self.inner.nu()
    }
    #[getter]
    fn robot_name(&self) -> String {
        self.inner.robot.name.clone()
    }
    #[getter]
    fn object_name(&self) -> String {
        self.inner.object.name.clone()
    }
    #[getter]
    fn joint_names(&self) -> Vec<String> {
        self.inner.robot.active_joint_names()
    }
    #[getter]
    fn frame_names(&self) -> Vec<String> {
        self.inner.robot.link_names()
    }
    #[getter]
    fn object_joint_names(&self) -> Vec<String> {
        self.inner.object.active_joint_names()
    }
    #[getter]
    fn object_frame_names(&self) -> Vec<String> {
        self.inner.object.link_names()
    }
    /// Robot joint limits as (lower, upper, velocity, effort) arrays of length nq.
    fn robot_limits(&self) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
        let l = self.inner.robot_limits();
        (
            l.iter().map(|v| v.lower).collect(),
            l.iter().map(|v| v.upper).collect(),
            l.iter().map(|v| v.velocity).collect(),
            l.iter().map(|v| v.effort).collect(),
        )
    }
    /// Object joint limits as (lower, upper) arrays of length no.
    fn object_limits(&self) -> (Vec<f64>, Vec<f64>) {
        let l = self.inner.object_limits();
        (l.iter().map(|v| v.lower).collect(), l.iter().map(|v| v.upper).collect())
    }
    /// Object damping and dry friction per object joint.
    fn object_dynamics(&self) -> (Vec<f64>, Vec<f64>) {
        let o = &self.inner.object;
        (
            o.active_joints.iter().map(|&j| o.joints[j].damping).collect(),
            o.active_joints.iter().map(|&j| o.joints[j].friction).collect(),
        )
    }
    fn object_joint_is_revolute(&self) -> bool {
        self.inner.object_is_revolute()
    }
    /// Object pose in the world as a 4 × 4 matrix.
    #[getter]
    fn object_pose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        pose_array(py, &self.inner.object_pose)
    }
    fn default_state(&self) -> Vec<f64> {
        self.inner.default_state()
    }
    fn home_configuration(&self) -> Vec<f64> {
        self.inner.home_configuration()
    }
    fn start_configuration(&self) -> Vec<f64> {
        self.inner.start_configuration()
    }
    fn work_configuration(&self) -> Vec<f64> {
        self.inner.roles.work.clone()
    }
    /// What the robot's parts are for (see `robot::RolesRow`).
    fn roles(&self) -> RolesRow {
        roles_row(&self.inner)
    }
    /// The visuals of the robot's and of the object's links (see `robot::VisualRow`).
    fn visuals(&self) -> (Vec<VisualRow>, Vec<VisualRow>) {
        (visual_rows(&self.inner.robot), visual_rows(&self.inner.object))
    }
    fn rollout_contact_links(&self) -> Vec<String> {
        self.inner
            .rollout_contact_links
            .iter()
            .map(|&l| self.inner.robot.links[l].name.clone())
            .collect()
    }
    /// The object's collision primitives as (link, kind, size, pose in the link frame as a row-major
    /// 4 × 4): kind "box" (size = half extents x, y, z), "sphere" (radius), "cylinder" and "capsule"
    /// (radius, half length along the primitive's z), "mesh" (a mesh's convex hull: half extents of
    /// its bounding box, which the pose centres), and for meshes the hull's vertices (else empty).
    fn object_collisions(&self) -> Vec<CollisionRow> {
        collision_rows(&self.inner.object)
    }
    /// The robot's collision primitives (its tool's included), as `object_collisions`.
    fn robot_collisions(&self) -> Vec<CollisionRow> {
        collision_rows(&self.inner.robot)
    }
    /// Every collision sphere, in order: (name, link, centre xyz, radius, checked against obstacles).
    fn spheres(&self) -> Vec<(String, String, [f64; 3], f64, bool)> {
        self.inner
            .spheres
            .iter()
            .map(|sp| {
                let (name, link, centre, radius) = self.sphere_row(sp);
                (name, link, centre, radius, sp.obstacles)
            })
            .collect()
    }
    /// The collision spheres checked against run-time obstacles as (name, link, centre xyz, radius).
    fn obstacle_spheres(&self) -> Vec<SphereRow> {
        self.inner
            .spheres
            .iter()
            .filter(|sp| sp.obstacles)
            .map(|sp| self.sphere_row(sp))
            .collect()
    }
    /// Self-collision spheres (those in a pair) as (name, link, centre xyz, radius) and the checked
    /// pairs (by name).
    fn self_collision(&self) -> (Vec<SphereRow>, Vec<(String, String)>) {
        let s = &self.inner;
        let paired = |i: usize| s.sphere_pairs.iter().any(|&(a, b)| a == i || b == i);
        (
            s.spheres
                .iter()
                .enumerate()
                .filter(|&(i, _)| paired(i))
                .map(|(_, sp)| self.sphere_row(sp))
                .collect(),
            s.sphere_pairs
                .iter()
                .map(|&(a, b)| (s.spheres[a].name.clone(), s.spheres[b].name.clone()))
                .collect(),
        )
    }
    /// (base link, frame, max) of the planar arm-reach limit (40), if declared.
    fn arm_reach(&self) -> Option<(String, String, f64)> {
        let s = &self.inner;
        s.arm_reach.as_ref().map(|a| {
            (
                s.robot.links[a.base_link].name.clone(),
                s.robot.links[a.frame_link].name.clone(),
                a.max,
            )
        })
    }

    /// World pose (4, 4) of a robot frame at q (nq,).
    fn fk<'py>(&self, py: Python<'py>, q: PyReadonlyArrayDyn<'py, f64>, frame: &str) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let nq = self.inner.nq() as isize;
        let pose = run(|| self.inner.fk(view("q", &q, &[nq])?, frame))?;
        pose_array(py, &pose)
    }

    /// World poses (M, 4, 4) of a robot frame for M configurations (M, nq).
    fn fk_many<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArrayDyn<'py, f64>,
        frame: &str,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let nq = self.inner.nq() as isize;
        let poses = run(|| self.inner.fk_many(view("q", &q, &[-1, nq])?, frame))?;
        poses_array(py, &poses)
    }

    /// Geometric Jacobian (6, nq) of a robot frame's origin, world frame, linear rows first.
    fn jacobian<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArrayDyn<'py, f64>,
        frame: &str,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let nq = self.inner.nq() as isize;
        let j = run(|| self.inner.jacobian(view("q", &q, &[nq])?, frame))?;
        array(py, j.transpose().as_slice().to_vec(), &[6, self.inner.nq()])
    }

    /// World pose (4, 4) of an object frame at object configuration o (no,).
    fn object_fk<'py>(
        &self,
        py: Python<'py>,
        o: PyReadonlyArrayDyn<'py, f64>,
        frame: &str,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let no = self.inner.no() as isize;
        let pose = run(|| self.inner.object_fk(view("o", &o, &[no])?, frame))?;
        pose_array(py, &pose)
    }

    /// World poses (M, 4, 4) of an object frame for M object configurations (M, no).
    fn object_fk_many<'py>(
        &self,
        py: Python<'py>,
        o: PyReadonlyArrayDyn<'py, f64>,
        frame: &str,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let no = self.inner.no() as isize;
        let poses = run(|| self.inner.object_fk_many(view("o", &o, &[-1, no])?, frame))?;
        poses_array(py, &poses)
    }

    /// Joint-space mass matrix (nq, nq) and gravity torque (nq,) of the robot at q (nq,).
    fn mass_matrix_and_gravity<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<(Array<'py>, Array<'py>)> {
        let nq = self.inner.nq();
        let (m, g) = run(|| self.inner.mass_matrix_and_gravity(view("q", &q, &[nq as isize])?))?;
        Ok((
            array(py, m.transpose().as_slice().to_vec(), &[nq, nq])?,
            array(py, g.as_slice().to_vec(), &[nq])?,
        ))
    }
}
