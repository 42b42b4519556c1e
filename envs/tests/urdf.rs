//! URDF loading: the shipped Panda, and clear errors for malformed descriptions.

use equigym_envs::robot::parse_urdf;
use equigym_envs::EnvError;

const PANDA: &str = include_str!("../../assets/panda/panda.urdf");

fn reason(text: &str) -> String {
    match parse_urdf(text) {
        Err(EnvError::Urdf { reason, .. }) => reason,
        other => panic!("expected a URDF error, got {other:?}"),
    }
}

#[test]
fn panda_loads_with_its_published_limits() {
    let robot = parse_urdf(PANDA).unwrap();
    assert_eq!(robot.dof(), 7);
    assert_eq!(robot.joints[3].lower, -3.0718);
    assert_eq!(robot.joints[5].upper, 3.7525);
    assert!((robot.max_gripper_width() - 0.08).abs() < 1e-12);
    assert!((robot.tcp_offset.translation.z - 0.1034).abs() < 1e-12);
    // Home posture of robosuite puts the TCP above the table, pointing down.
    let base = nalgebra::Isometry3::translation(-0.56, 0.0, 0.912);
    let home = equigym_envs::tasks::tabletop::panda_home();
    let tcp = robot.tcp_pose(&base, &home);
    assert!(tcp.translation.z > 0.9 && tcp.translation.z < 1.1, "{tcp:?}");
    let down = tcp.rotation * nalgebra::Vector3::z();
    assert!(down.z < -0.99, "TCP z axis should point down, got {down:?}");
}

#[test]
fn malformed_descriptions_name_the_problem() {
    assert!(reason("<robot").contains("not a valid URDF"));
    let no_hand = PANDA.replace("type=\"prismatic\"", "type=\"fixed\"");
    assert!(reason(&no_hand).contains("no hand found"));
    let mesh = PANDA.replacen("<capsule radius=\"0.06\" length=\"0.2\"/>", "<mesh filename=\"link1.stl\"/>", 1);
    assert!(reason(&mesh).contains("mesh 'link1.stl'"));
    let dangling = PANDA.replace("<parent link=\"panda_link3\"/>", "<parent link=\"panda_link33\"/>");
    assert!(reason(&dangling).contains("unknown link 'panda_link33'"));
    let bad_limits = PANDA.replace("lower=\"-1.7628\" upper=\"1.7628\"", "lower=\"1\" upper=\"-1\"");
    assert!(reason(&bad_limits).contains("not an interval"));
}

#[test]
fn a_different_serial_arm_loads() {
    // A 3-joint arm with a two-finger hand and no TCP link.
    let text = r#"<robot name="toy">
      <link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/>
      <link name="hand"><inertial><mass value="0.5"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>
      <link name="fa"><inertial><mass value="0.01"/><inertia ixx="1e-6" ixy="0" ixz="0" iyy="1e-6" iyz="0" izz="1e-6"/></inertial></link>
      <link name="fb"><inertial><mass value="0.01"/><inertia ixx="1e-6" ixy="0" ixz="0" iyy="1e-6" iyz="0" izz="1e-6"/></inertial></link>
      <joint name="j1" type="continuous"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/></joint>
      <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
      <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
      <joint name="wrist" type="fixed"><parent link="l3"/><child link="hand"/><origin xyz="0.1 0 0"/></joint>
      <joint name="ja" type="prismatic"><parent link="hand"/><child link="fa"/><axis xyz="0 1 0"/><limit lower="0" upper="0.03" effort="20" velocity="0.1"/></joint>
      <joint name="jb" type="prismatic"><parent link="hand"/><child link="fb"/><axis xyz="0 -1 0"/><limit lower="0" upper="0.03" effort="20" velocity="0.1"/></joint>
    </robot>"#;
    let robot = parse_urdf(text).unwrap();
    assert_eq!(robot.dof(), 3);
    assert!(robot.joints[0].lower.is_infinite());
    assert!((robot.tcp_offset.translation.z - 0.045).abs() < 1e-12);
}
