//! The URDF reader's own checks: a cylinder capped by spheres read as a capsule, the shipped
//! descriptions, and the refusal of deep nesting, non-finite or non-physical inertials and bad limits.

use super::*;

const ROBOT: &str = include_str!("../../../assets/robots/royalpanda.urdf");
const SHELF: &str = include_str!("../../../assets/objects/shelf.urdf");

fn shelf_with(from: &str, to: &str) -> String {
    assert!(SHELF.contains(from), "fixture text '{from}' not in shelf.urdf");
    SHELF.replacen(from, to, 1)
}

fn urdf_error(text: &str) -> String {
    match parse_urdf("object", text) {
        Err(SabreError::Urdf { detail, .. }) => detail,
        other => panic!("expected a URDF error, got {other:?}"),
    }
}

fn link_collisions(body: &str) -> Vec<Collision> {
    let text = format!(
        r#"<robot name="r"><link name="a">{body}</link><link name="b"/>
        <joint name="j" type="revolute"><parent link="a"/><child link="b"/>
        <limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>"#
    );
    let parsed = parse_urdf("robot", &text).unwrap().description;
    parsed.links[parsed.link_index["a"]].collisions.clone()
}

#[test]
fn a_cylinder_with_spheres_on_both_caps_reads_as_the_capsule() {
    let capsule = link_collisions(
        r#"<collision name="c"><origin xyz="0.1 0.2 0.3" rpy="0.3 1.2 -0.4"/>
           <geometry><capsule radius="0.05" length="0.2"/></geometry></collision>"#,
    );
    // Cap centres by hand: origin + R(rpy) (0, 0, ±0.1), R's third column (cy sp cr + sy sr, sy sp cr − cy sr, cp cr).
    let (r, p, y) = (0.3f64, 1.2f64, -0.4f64);
    let z = [
        y.cos() * p.sin() * r.cos() + y.sin() * r.sin(),
        y.sin() * p.sin() * r.cos() - y.cos() * r.sin(),
        p.cos() * r.cos(),
    ];
    let cap = |s: f64| format!("{} {} {}", 0.1 + s * 0.1 * z[0], 0.2 + s * 0.1 * z[1], 0.3 + s * 0.1 * z[2]);
    let written = link_collisions(&format!(
        r#"<collision><origin xyz="{}" rpy="0 0 0"/><geometry><sphere radius="0.05"/></geometry></collision>
           <collision name="c"><origin xyz="0.1 0.2 0.3" rpy="0.3 1.2 -0.4"/>
           <geometry><cylinder radius="0.05" length="0.2"/></geometry></collision>
           <collision><origin xyz="{}" rpy="0 0 0"/><geometry><sphere radius="0.05"/></geometry></collision>"#,
        cap(1.0),
        cap(-1.0)
    ));
    assert_eq!(written.len(), 1, "{written:?}");
    assert_eq!(written[0].shape, capsule[0].shape);
    assert_eq!(written[0].name.as_deref(), Some("c"));
    assert!((written[0].origin.to_homogeneous() - capsule[0].origin.to_homogeneous()).norm() < 1e-15);
}

#[test]
fn spheres_that_do_not_close_the_cylinder_stay_separate() {
    let other_radius = link_collisions(
        r#"<collision><geometry><cylinder radius="0.05" length="0.2"/></geometry></collision>
           <collision><origin xyz="0 0 0.1"/><geometry><sphere radius="0.06"/></geometry></collision>
           <collision><origin xyz="0 0 -0.1"/><geometry><sphere radius="0.05"/></geometry></collision>"#,
    );
    assert_eq!(other_radius.len(), 3);
    let one_cap = link_collisions(
        r#"<collision><geometry><cylinder radius="0.05" length="0.2"/></geometry></collision>
           <collision><origin xyz="0 0 0.1"/><geometry><sphere radius="0.05"/></geometry></collision>
           <collision><origin xyz="0 0.01 -0.1"/><geometry><sphere radius="0.05"/></geometry></collision>"#,
    );
    assert_eq!(one_cap.len(), 3);
    assert!(matches!(one_cap[0].shape, Shape::Cylinder { .. }));
}

#[test]
fn the_shipped_robot_is_standard_urdf_and_keeps_its_capsules() {
    assert!(!ROBOT.contains("<capsule"), "standard URDF has no <capsule>");
    let robot = parse_urdf("robot", ROBOT).unwrap().description;
    let arm: Vec<&Collision> = (0..=7)
        .flat_map(|k| &robot.links[robot.link_index[&format!("panda_link{k}")]].collisions)
        .collect();
    assert_eq!(arm.len(), 9);
    assert!(arm.iter().all(|c| matches!(c.shape, Shape::Capsule { .. })), "{arm:?}");
}

#[test]
fn an_inertial_without_mass_or_inertia_is_completed_and_its_parts_recorded() {
    let doc_text = r#"<robot><link name="a"><inertial><origin xyz="1 2 3"/><mass value="2"/></inertial></link><link name="b"><inertial/></link></robot>"#;
    let doc = roxmltree::Document::parse(doc_text).unwrap();
    let completed = with_complete_inertials(doc_text, &doc);
    assert!(completed.contains(r#"<mass value="2"/><inertia ixx="0""#), "{completed}");
    assert!(completed.contains(r#"<inertial><mass value="0"/><inertia"#), "{completed}");
    let present = inertial_elements(&doc);
    assert_eq!(present["a"], (true, true, false));
    assert_eq!(present["b"], (false, false, false));
}

#[test]
fn the_shipped_assets_pass_every_value_check() {
    parse_urdf("robot", ROBOT).unwrap();
    for (name, text) in crate::model::scene::BUILTIN_OBJECTS {
        parse_urdf(name, text).unwrap();
    }
}

#[test]
fn deep_nesting_is_refused_before_the_recursive_parser_sees_it() {
    let deep = format!("<robot name=\"r\">{}{}</robot>", "<a>".repeat(20_000), "</a>".repeat(20_000));
    assert!(urdf_error(&deep).contains("nested deeper"));
    // The root element sits at depth 1 under the document node.
    let nested = |levels: usize| format!("<robot>{}{}</robot>", "<a>".repeat(levels), "</a>".repeat(levels));
    let at_limit = nested(MAX_XML_DEPTH - 1);
    assert!(check_depth("t", &roxmltree::Document::parse(&at_limit).unwrap()).is_ok());
    let beyond = nested(MAX_XML_DEPTH);
    assert!(check_depth("t", &roxmltree::Document::parse(&beyond).unwrap()).is_err());
}

#[test]
fn non_finite_inertial_origins_are_refused() {
    let text = shelf_with("<origin xyz=\"0.231338 0 0.382559\"", "<origin xyz=\"0.231338 nan 0.382559\"");
    assert!(urdf_error(&text).contains("inertial origin"));
}

#[test]
fn negative_or_non_physical_inertia_is_refused() {
    for (ixx, iyy, izz) in [(-0.1, 0.1, 0.1), (0.0, 0.1, 0.1), (1.0, 0.1, 0.1)] {
        let doc = format!(
            "<robot name=\"o\"><link name=\"base\"/><link name=\"door\"><inertial><mass value=\"1\"/><inertia ixx=\"{ixx}\" ixy=\"0\" ixz=\"0\" iyy=\"{iyy}\" iyz=\"0\" izz=\"{izz}\"/></inertial></link>\
             <joint name=\"j\" type=\"revolute\"><parent link=\"base\"/><child link=\"door\"/><axis xyz=\"0 0 1\"/><limit lower=\"0\" upper=\"1\" effort=\"1\" velocity=\"1\"/></joint></robot>"
        );
        assert!(urdf_error(&doc).contains("non-physical inertia"), "{ixx} {iyy} {izz}");
    }
}

#[test]
fn negative_limits_and_infinite_dynamics_are_refused() {
    let joint = |limit: &str, dynamics: &str| {
        format!(
            "<robot name=\"o\"><link name=\"base\"/><link name=\"door\"/>\
             <joint name=\"j\" type=\"revolute\"><parent link=\"base\"/><child link=\"door\"/><axis xyz=\"0 0 1\"/>{limit}{dynamics}</joint></robot>"
        )
    };
    let ok = joint(
        "<limit lower=\"0\" upper=\"1\" effort=\"0\" velocity=\"0\"/>",
        "<dynamics damping=\"1\" friction=\"0.5\"/>",
    );
    let limits = parse_urdf("object", &ok).unwrap().description.joints[0].limits;
    assert!(
        limits.effort.is_infinite() && limits.velocity.is_infinite(),
        "0 means no bound"
    );
    for (limit, dynamics, says) in [
        (
            "<limit lower=\"0\" upper=\"1\" effort=\"-5\" velocity=\"1\"/>",
            "",
            "effort limit -5",
        ),
        (
            "<limit lower=\"0\" upper=\"1\" effort=\"5\" velocity=\"-1\"/>",
            "",
            "velocity limit -1",
        ),
        (
            "<limit lower=\"0\" upper=\"1\" effort=\"inf\" velocity=\"1\"/>",
            "",
            "effort limit inf",
        ),
        (
            "<limit lower=\"0\" upper=\"1\" effort=\"1\" velocity=\"1\"/>",
            "<dynamics damping=\"inf\"/>",
            "damping inf",
        ),
        (
            "<limit lower=\"0\" upper=\"1\" effort=\"1\" velocity=\"1\"/>",
            "<dynamics damping=\"1\" friction=\"-1\"/>",
            "friction -1",
        ),
    ] {
        assert!(urdf_error(&joint(limit, dynamics)).contains(says), "{limit} {dynamics}");
    }
}
