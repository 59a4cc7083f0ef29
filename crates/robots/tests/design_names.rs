//! Every robot names each entry of its design vector (what an operator building a prototype
//! reads the dimensions by): one non-empty, distinct name per entry.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

#[test]
fn every_robot_names_each_design_entry_once() {
    for name in coadapt_robots::ENV_NAMES {
        let spec = coadapt_robots::make(name).unwrap().spec().clone();
        assert_eq!(spec.design_names.len(), spec.design_dim(), "{name}: {:?}", spec.design_names);
        assert!(spec.design_names.iter().all(|n| !n.trim().is_empty()), "{name}: {:?}", spec.design_names);
        let mut unique = spec.design_names.clone();
        unique.sort();
        unique.dedup();
        assert_eq!(unique.len(), spec.design_dim(), "{name}: names repeat: {:?}", spec.design_names);
    }
    let cheetah = coadapt_robots::make("half-cheetah").unwrap().spec().design_names.clone();
    assert_eq!(cheetah, ["back thigh", "back shin", "back foot", "front thigh", "front shin", "front foot"]);
}
