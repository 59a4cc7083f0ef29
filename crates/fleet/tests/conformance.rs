//! The fleet's conformance suite over every transport: in-process channels, iceoryx2 shared
//! memory and gRPC on a free port.

use std::time::Duration;

use coadapt_fleet::conformance::{self, ACT, FleetUnderTest, OBS};
use coadapt_transport::messages::Dims;

const ACTORS: usize = 2;

fn in_process() -> FleetUnderTest {
    let (learner, actors, optimizer) = coadapt_transport::in_process::fleet(ACTORS);
    FleetUnderTest { learner, actors, guard: Box::new(optimizer) }
}

fn shm(test: &str) -> FleetUnderTest {
    let cfg = coadapt_shm::ShmConfig { fleet: format!("coadapt-fleet-{}-{test}", std::process::id()), ..coadapt_shm::ShmConfig::default() };
    let learner = coadapt_shm::learner_links(&cfg).expect("shm learner");
    let actors = (1..=ACTORS as u64).map(|id| coadapt_shm::actor_links(&cfg, id).expect("shm actor")).collect();
    FleetUnderTest { learner, actors, guard: Box::new(()) }
}

fn grpc() -> FleetUnderTest {
    let cfg = coadapt_grpc::GrpcConfig {
        rpc_timeout: Duration::from_secs(2),
        connect_timeout: Duration::from_secs(2),
        heartbeat: Duration::from_millis(100),
        reconnect_backoff_max: Duration::from_millis(300),
        max_episode_steps: 20,
        ..coadapt_grpc::GrpcConfig::default()
    };
    let (learner, server) = coadapt_grpc::serve_learner("127.0.0.1:0".parse().expect("address"), &cfg).expect("gRPC learner");
    server.expect_dims(Dims { obs: OBS, act: ACT, design: 0 });
    let endpoint = format!("http://{}", server.local_addr());
    let actors = (1..=ACTORS as u64).map(|id| coadapt_grpc::actor_links(&endpoint, id, &cfg).expect("gRPC actor")).collect();
    FleetUnderTest { learner, actors, guard: Box::new(server) }
}

macro_rules! over_every_transport {
    ($($name:ident),* $(,)?) => {
        mod in_process { $( #[test] fn $name() { super::conformance::$name(super::in_process()) } )* }
        mod shm { $( #[test] fn $name() { super::conformance::$name(super::shm(stringify!($name))) } )* }
        mod grpc { $( #[test] fn $name() { super::conformance::$name(super::grpc()) } )* }
    };
}

over_every_transport!(
    every_job_comes_back_exactly_once,
    a_silent_actors_job_goes_to_another_after_its_lease,
    a_restarted_episode_comes_back_whole,
    a_refused_episode_goes_out_again_and_a_fatal_one_fails,
    bad_or_idle_actors_cannot_keep_a_job,
    a_wait_without_actors_ends,
);
