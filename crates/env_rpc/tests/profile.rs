//! Reading a server's specs: the coadapt profile, and any dm_env_rpc server that has never heard
//! of it (no `design` observation: a fixed-design environment; its own uids and action name).

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::BoxSpace;
use coadapt_env_rpc::profile::{Profile, ProfileError};
use coadapt_wire::dm_env_rpc::v1::ActionObservationSpecs;
use coadapt_wire::tensor::float_spec;

fn plain(actions: &[(u64, &str)]) -> ActionObservationSpecs {
    ActionObservationSpecs {
        actions: actions.iter().map(|&(uid, name)| (uid, float_spec(name, &[1], Some((&[-2.0], &[2.0]))))).collect(),
        observations: [
            (11, float_spec("observation", &[3], None)),
            (12, float_spec("reward", &[], None)),
            (13, float_spec("discount", &[], Some((&[0.0], &[1.0])))),
        ]
        .into(),
    }
}

#[test]
fn a_server_without_a_design_is_a_fixed_design_environment() {
    let (p, uids) = Profile::from_specs(&plain(&[(7, "torque")])).unwrap();
    assert_eq!((p.state_dim, p.design.dim()), (3, 0));
    assert_eq!(p.action, BoxSpace::new(vec![-2.0], vec![2.0]).unwrap());
    assert_eq!((uids.action, uids.observation, uids.reward, uids.discount, uids.design), (7, 11, 12, 13, None));
    assert!(!uids.coadapt());
    // Two actions, neither named `action`: which one is meant cannot be guessed.
    let e = Profile::from_specs(&plain(&[(1, "left"), (2, "right")])).unwrap_err();
    assert!(matches!(e, ProfileError::Missing { name: "action", .. }), "{e}");
    assert!(e.to_string().contains("its actions: `left`, `right`"), "{e}");
}

#[test]
fn the_coadapt_profile_still_reads_its_design() {
    let p = Profile { state_dim: 17, action: BoxSpace::uniform(6, -1.0, 1.0), design: BoxSpace::uniform(6, 0.5, 2.0) };
    let (read, uids) = Profile::from_specs(&p.specs()).unwrap();
    assert_eq!(read, p);
    assert!(uids.coadapt());
    // Without a reward there is nothing to learn from: said with what the server has.
    let mut s = plain(&[(7, "torque")]);
    s.observations.remove(&12);
    let e = Profile::from_specs(&s).unwrap_err().to_string();
    assert!(e.contains("no observation named `reward`") && e.contains("`discount`, `observation`"), "{e}");
}
