//! A robot as sabre uses it: its URDF tree with the tool attached and the held joints fixed, and the
//! role of each part (control frame, base, home and start postures, wrist sensor) declared, detected
//! from the tree, or absent.

use nalgebra::{Isometry3, Vector3};

use super::kinematics::{Joint, JointKind, JointLimits, KinematicTree};
use super::roles::{tool_text, BaseDecl, RoleDecls, ToolSpec};
use super::urdf::parse_urdf;
use crate::error::{Result, SabreError};

/// A holonomic base as three movable joints, by q index: prismatic along world x and y, then a
/// revolute about the vertical. Its velocities are world-frame rates (ẋ, ẏ, yaw rate).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlanarBase {
    pub x: usize,
    pub y: usize,
    pub yaw: usize,
}

impl PlanarBase {
    /// The q indices (x, y, yaw).
    pub fn indices(&self) -> [usize; 3] {
        [self.x, self.y, self.yaw]
    }
}

/// How each role was found: "declared" (URDF block or scene option), "detected" (from the tree),
/// "tool" (the attached tool's own declaration) or "none".
#[derive(Debug, Clone, PartialEq)]
pub struct RoleOrigins {
    pub tool_frame: &'static str,
    pub base: &'static str,
    pub wrist_sensor: &'static str,
    /// Per held joint: "declared", or "off the tool frame's chain" (held by the default rule).
    pub held: Vec<&'static str>,
}

/// The roles of the robot's parts, as the rest of sabre reads them.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotRoles {
    /// The control frame (link index) tasks steer, if the robot has one.
    pub tool_frame: Option<usize>,
    /// A holonomic base, or None for a fixed-base arm.
    pub base: Option<PlanarBase>,
    /// The link the base's footprint belongs to (the planar base's body, or the root).
    pub base_link: usize,
    /// (nq) the home, start and working postures.
    pub home: Vec<f64>,
    pub start: Vec<f64>,
    pub work: Vec<f64>,
    /// Joints fixed at a value (rad or m), by name, in the URDF's joint order.
    pub held: Vec<(String, f64)>,
    /// The tool that was attached.
    pub tool: Option<ToolSpec>,
    /// The link carrying the wrist force-torque sensor.
    pub wrist_sensor: usize,
    pub origins: RoleOrigins,
}

fn unknown_joint(source: &str, what: &str, name: &str, tree: &KinematicTree) -> SabreError {
    SabreError::urdf(
        source,
        format!(
            "{what} names joint '{name}', which is not a movable joint of the robot; its movable joints are: {}",
            tree.active_joint_names().join(", ")
        ),
    )
}

fn movable(tree: &KinematicTree, name: &str) -> Option<usize> {
    tree.active_joints.iter().copied().find(|&j| tree.joints[j].name == name)
}

/// Attaches `tool` to `tree`: its fragment's links and joints are appended (robot coordinates keep
/// their indices) and its root link is fixed to `tool.parent`. Returns the tree and the control
/// frame the fragment declares.
pub fn attach_tool(tree: KinematicTree, tool: &ToolSpec, source: &str) -> Result<(KinematicTree, Option<String>)> {
    let (name, text) = tool_text(tool)?;
    let fragment = parse_urdf(&name, &text)?;
    let parent = tree.link_id(&tool.parent).ok_or_else(|| {
        SabreError::urdf(
            source,
            format!(
                "the tool's parent link '{}' is not a link of the robot; its links are: {}",
                tool.parent,
                tree.link_names().join(", ")
            ),
        )
    })?;
    let part = fragment.description;
    for l in &part.links {
        if tree.link_id(&l.name).is_some() {
            return Err(SabreError::urdf(
                source,
                format!("the tool's link '{}' is also a link of the robot", l.name),
            ));
        }
    }
    let mount_name = format!("{}_mount", part.links[part.root].name);
    for j in part.joints.iter().map(|j| &j.name).chain([&mount_name]) {
        if tree.joints.iter().any(|k| &k.name == j) {
            return Err(SabreError::urdf(
                source,
                format!("the tool's joint '{j}' is also a joint of the robot"),
            ));
        }
    }
    let offset = tree.links.len();
    let mut links = tree.links;
    links.extend(part.links);
    for link in &mut links {
        link.parent_joint = None;
    }
    let mut joints = tree.joints;
    joints.extend(part.joints.into_iter().map(|j| Joint {
        parent: j.parent + offset,
        child: j.child + offset,
        ..j
    }));
    joints.push(Joint {
        name: mount_name,
        kind: JointKind::Fixed,
        parent,
        child: part.root + offset,
        origin: tool.origin(),
        axis: Vector3::x(),
        q_index: None,
        limits: JointLimits {
            lower: 0.0,
            upper: 0.0,
            velocity: f64::INFINITY,
            effort: f64::INFINITY,
        },
        damping: 0.0,
        friction: 0.0,
    });
    let joined = KinematicTree::new(tree.name, links, joints, source)?;
    let frame = tool.frame.clone().or(fragment.extension.roles.tool_frame);
    Ok((joined, frame))
}

/// The home posture over every movable joint of `tree`: the declared value, else 0 where it lies
/// within the joint's limits, else the middle of finite limits, else the limit nearest 0.
fn home_posture(tree: &KinematicTree, declared: &[(String, f64)], source: &str) -> Result<Vec<f64>> {
    for (name, value) in declared {
        let j = movable(tree, name).ok_or_else(|| unknown_joint(source, "<home>", name, tree))?;
        within_limits(tree, j, *value, "home", source)?;
    }
    Ok(tree
        .active_joints
        .iter()
        .map(|&j| {
            let joint = &tree.joints[j];
            let l = joint.limits;
            declared.iter().find(|(n, _)| n == &joint.name).map_or_else(
                || {
                    if l.lower <= 0.0 && 0.0 <= l.upper {
                        0.0
                    } else if l.lower.is_finite() && l.upper.is_finite() {
                        0.5 * (l.lower + l.upper)
                    } else {
                        0.0_f64.clamp(l.lower, l.upper)
                    }
                },
                |(_, v)| *v,
            )
        })
        .collect())
}

fn within_limits(tree: &KinematicTree, j: usize, value: f64, what: &str, source: &str) -> Result<()> {
    let l = tree.joints[j].limits;
    if value.is_finite() && l.lower <= value && value <= l.upper {
        Ok(())
    } else {
        Err(SabreError::urdf(
            source,
            format!(
                "{what} value {value} of joint '{}' is outside its limits [{}, {}]",
                tree.joints[j].name, l.lower, l.upper
            ),
        ))
    }
}

/// Leaf links without geometry or mass (pure frames) that the most movable joints move; the one
/// such frame is the detected control frame.
fn detect_tool_frame(tree: &KinematicTree) -> Option<usize> {
    let leaf = |l: usize| !tree.joints.iter().any(|j| j.parent == l);
    let frame = |l: usize| {
        let link = &tree.links[l];
        link.collisions.is_empty() && link.visuals.is_empty() && link.inertial.is_none()
    };
    let candidates: Vec<usize> = (0..tree.links.len()).filter(|&l| leaf(l) && frame(l)).collect();
    let depth = |l: usize| tree.ancestor_active_joints(l).len();
    let deepest = candidates.iter().map(|&l| depth(l)).max().filter(|&d| d > 0)?;
    let at: Vec<usize> = candidates.into_iter().filter(|&l| depth(l) == deepest).collect();
    (at.len() == 1).then(|| at[0])
}

/// (explicit holds, then the default ones) as (joint index, value, how), checked.
fn holds(
    tree: &KinematicTree,
    declared: &[(String, f64)],
    tool_frame: Option<usize>,
    home: &[f64],
    source: &str,
) -> Result<Vec<(usize, f64, &'static str)>> {
    let mut out = Vec::new();
    for (name, value) in declared {
        let j = movable(tree, name).ok_or_else(|| unknown_joint(source, "hold", name, tree))?;
        within_limits(tree, j, *value, "held", source)?;
        out.push((j, *value, "declared"));
    }
    if let Some(frame) = tool_frame {
        let chain = tree.ancestor_active_joints(frame);
        for (i, &j) in tree.active_joints.iter().enumerate() {
            if !chain.contains(&j) && !out.iter().any(|(k, _, _)| *k == j) {
                out.push((j, home[i], "off the tool frame's chain"));
            }
        }
    }
    out.sort_by_key(|(j, _, _)| *j);
    Ok(out)
}

/// World direction of a movable joint's axis with every coordinate at 0.
fn world_axis(tree: &KinematicTree, j: usize) -> Vector3<f64> {
    let poses = tree.link_poses(&Isometry3::identity(), &vec![0.0; tree.nq()]);
    tree.joint_axis_world(&poses, j).0
}

/// The planar base that joints `chain` (joint indices, root first) make, or why they make none.
fn planar_base(tree: &KinematicTree, chain: &[usize]) -> std::result::Result<PlanarBase, String> {
    let along = |j: usize, axis: Vector3<f64>| (world_axis(tree, j) - axis).norm() < 1e-9;
    let (mut x, mut y, mut yaw) = (None, None, None);
    for (k, &j) in chain.iter().enumerate() {
        let joint = &tree.joints[j];
        match joint.kind {
            JointKind::Prismatic if along(j, Vector3::x()) && x.is_none() && yaw.is_none() => x = Some(j),
            JointKind::Prismatic if along(j, Vector3::y()) && y.is_none() && yaw.is_none() => y = Some(j),
            JointKind::Revolute if world_axis(tree, j).z.abs() > 1.0 - 1e-9 && k == 2 => yaw = Some(j),
            _ => {
                return Err(format!(
                    "joint '{}' is not a base joint: a planar base is a prismatic joint along world +x and one along \
                     +y (in either order) followed by a revolute joint about the vertical, before every other movable joint",
                    joint.name
                ))
            }
        }
    }
    match (x, y, yaw) {
        (Some(x), Some(y), Some(yaw)) => {
            let q = |j: usize| tree.joints[j].q_index.expect("movable");
            Ok(PlanarBase {
                x: q(x),
                y: q(y),
                yaw: q(yaw),
            })
        }
        _ => Err("a planar base needs three joints: x, y and yaw".into()),
    }
}

/// The first three movable joints along the chain from the root (to the tool frame when there is
/// one), root first; fewer when the chain branches or ends before.
fn root_chain(tree: &KinematicTree, tool_frame: Option<usize>) -> Vec<usize> {
    if let Some(frame) = tool_frame {
        return tree.ancestor_active_joints(frame).iter().copied().take(3).collect();
    }
    let mut chain: Vec<usize> = Vec::new();
    while chain.len() < 3 {
        let next: Vec<usize> = tree
            .active_joints
            .iter()
            .copied()
            .filter(|&j| tree.ancestor_active_joints(tree.joints[j].child) == [chain.as_slice(), &[j]].concat())
            .collect();
        if next.len() != 1 {
            break;
        }
        chain.push(next[0]);
    }
    chain
}

/// The base: declared (checked) or detected; its body link; and how it was found.
fn base_role(
    tree: &KinematicTree,
    declared: Option<&BaseDecl>,
    tool_frame: Option<usize>,
    source: &str,
) -> Result<(Option<PlanarBase>, usize, &'static str)> {
    let link = |name: &Option<String>, default: usize| -> Result<usize> {
        name.as_ref().map_or(Ok(default), |n| {
            tree.link_id(n)
                .ok_or_else(|| SabreError::urdf(source, format!("the base link '{n}' is not a link of the robot")))
        })
    };
    match declared {
        Some(BaseDecl::Fixed { link: l }) => Ok((None, link(l, tree.root)?, "declared")),
        Some(BaseDecl::Planar { joints, link: l }) => {
            let ids = joints
                .iter()
                .map(|n| movable(tree, n).ok_or_else(|| unknown_joint(source, "the base", n, tree)))
                .collect::<Result<Vec<_>>>()?;
            let chain = root_chain(tree, tool_frame);
            let mut ordered = ids.clone();
            ordered.sort_by_key(|&j| tree.ancestor_active_joints(tree.joints[j].child).len());
            if chain != ordered {
                return Err(SabreError::urdf(
                    source,
                    format!("the base joints {joints:?} must be the first three movable joints from the root"),
                ));
            }
            let base = planar_base(tree, &ordered).map_err(|e| SabreError::urdf(source, e))?;
            let yaw = tree.active_joints[base.yaw];
            Ok((Some(base), link(l, tree.joints[yaw].child)?, "declared"))
        }
        None => {
            let chain = root_chain(tree, tool_frame);
            match planar_base(tree, &chain) {
                Ok(base) if chain.len() == 3 => Ok((Some(base), tree.joints[tree.active_joints[base.yaw]].child, "detected")),
                _ => Ok((None, tree.root, "detected")),
            }
        }
    }
}

/// The tree with `decls.tool` attached and its held joints fixed, and the roles of its parts.
pub fn assemble(tree: KinematicTree, decls: &RoleDecls, source: &str) -> Result<(KinematicTree, RobotRoles)> {
    let (tree, tool_declared_frame) = match &decls.tool {
        Some(tool) => attach_tool(tree, tool, source)?,
        None => (tree, None),
    };
    let (frame_name, mut frame_origin) = match (&decls.tool_frame, tool_declared_frame) {
        (Some(name), _) => (Some(name.clone()), "declared"),
        (None, Some(name)) => (Some(name), "tool"),
        (None, None) => (None, "detected"),
    };
    let tool_frame = match &frame_name {
        Some(name) => Some(tree.link_id(name).ok_or_else(|| {
            SabreError::urdf(
                source,
                format!(
                    "the tool frame '{name}' is not a link of the robot; its links are: {}",
                    tree.link_names().join(", ")
                ),
            )
        })?),
        None => detect_tool_frame(&tree),
    };
    if tool_frame.is_none() {
        frame_origin = "none";
    }
    let home = home_posture(&tree, &decls.home, source)?;
    let held = holds(&tree, &decls.hold, tool_frame, &home, source)?;
    let kept: Vec<usize> = (0..tree.nq())
        .filter(|&i| !held.iter().any(|(j, _, _)| tree.active_joints[i] == *j))
        .collect();
    let fixed: Vec<(usize, f64)> = held.iter().map(|&(j, v, _)| (j, v)).collect();
    let held_names: Vec<(String, f64)> = held.iter().map(|&(j, v, _)| (tree.joints[j].name.clone(), v)).collect();
    let tree = tree.with_joints_fixed(&fixed, source)?;
    let home: Vec<f64> = kept.iter().map(|&i| home[i]).collect();
    let start = posture(&tree, &home, &decls.start, "start", source)?;
    let work = posture(&tree, &home, &decls.work, "work", source)?;
    let (base, base_link, base_origin) = base_role(&tree, decls.base.as_ref(), tool_frame, source)?;
    let (wrist_sensor, wrist_origin) = wrist_sensor(&tree, decls, tool_frame, source)?;
    let roles = RobotRoles {
        tool_frame,
        base,
        base_link,
        home,
        start,
        work,
        held: held_names,
        tool: decls.tool.clone(),
        wrist_sensor,
        origins: RoleOrigins {
            tool_frame: frame_origin,
            base: base_origin,
            wrist_sensor: wrist_origin,
            held: held.iter().map(|&(_, _, how)| how).collect(),
        },
    };
    Ok((tree, roles))
}

/// `home` with the declared values of posture `what` over it.
fn posture(tree: &KinematicTree, home: &[f64], declared: &[(String, f64)], what: &str, source: &str) -> Result<Vec<f64>> {
    let mut out = home.to_vec();
    for (name, value) in declared {
        let j = movable(tree, name).ok_or_else(|| unknown_joint(source, &format!("<{what}>"), name, tree))?;
        within_limits(tree, j, *value, what, source)?;
        out[tree.joints[j].q_index.expect("movable")] = *value;
    }
    Ok(out)
}

/// The wrist sensor's link: declared; else the link the tool is fixed to; else the link after the
/// last movable joint that moves the tool frame; else the child of the last movable joint.
fn wrist_sensor(
    tree: &KinematicTree,
    decls: &RoleDecls,
    tool_frame: Option<usize>,
    source: &str,
) -> Result<(usize, &'static str)> {
    if let Some(name) = &decls.wrist_sensor {
        let link = tree
            .link_id(name)
            .ok_or_else(|| SabreError::urdf(source, format!("the wrist sensor's link '{name}' is not a link of the robot")))?;
        return Ok((link, "declared"));
    }
    if let Some(tool) = &decls.tool {
        return Ok((tree.link_id(&tool.parent).expect("the tool is attached to it"), "tool"));
    }
    let last = tool_frame
        .and_then(|f| tree.ancestor_active_joints(f).last().copied())
        .or_else(|| tree.active_joints.last().copied());
    Ok((last.map_or(tree.root, |j| tree.joints[j].child), "detected"))
}
