//! Between processes: the test binary re-runs itself as the child (`child` below, which does
//! nothing unless the role variable is set).

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;

use coadapt_shm::{ShmConfig, cleanup_stale, queue_receiver, queue_sender, topic_publisher, topic_subscriber};
use coadapt_transport::conformance::{chunk, weights};
use coadapt_transport::{ExperienceChunk, Publisher, Receiver, Sender, Subscriber, TransportError, Weights};

const ROLE: &str = "COADAPT_SHM_TEST_ROLE";
const FLEET: &str = "COADAPT_SHM_TEST_FLEET";
const LONG: Duration = Duration::from_secs(20);
/// 1 MiB of f32 policy parameters.
const MIB: usize = 1 << 18;

/// The two parent tests take turns. iceoryx2 removes the machine's dead nodes whenever a node
/// is created or dropped (`cleanup-dead-nodes-on-creation`, its default), so a neighbour test
/// starting or ending its nodes may clean the killed child before `cleanup_stale` is called and
/// leave it nothing to count (CI failed that way once).
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn cfg(fleet: String) -> ShmConfig {
    ShmConfig { fleet, ..ShmConfig::default() }
}

#[test]
fn child() {
    let (Ok(role), Ok(fleet)) = (std::env::var(ROLE), std::env::var(FLEET)) else { return };
    let cfg = cfg(fleet);
    if role == "idle" {
        let _sub = topic_subscriber::<Weights>(&cfg, "w").expect("subscriber");
        println!("READY");
        std::thread::sleep(Duration::from_secs(600));
        return;
    }
    let mut publisher = topic_publisher::<Weights>(&cfg, "w").expect("publisher");
    let mut tx = queue_sender::<ExperienceChunk>(&cfg, "exp").expect("sender");
    match role.as_str() {
        "publish" => {
            for v in 1..=3 {
                publisher.publish(weights(v, MIB)).expect("publish");
            }
            for i in 0..100 {
                tx.send(chunk(i)).expect("send");
            }
            // Dropping the sender waits until the parent has taken every chunk.
        }
        "hang" => {
            publisher.publish(weights(1, MIB)).expect("publish");
            tx.send(chunk(0)).expect("send");
            // libtest has written "test child ... " without a newline: READY ends that line.
            println!("READY");
            std::thread::sleep(Duration::from_secs(600));
        }
        other => panic!("unknown role {other}"),
    }
}

fn spawn(role: &str, fleet: &str) -> std::process::Child {
    Command::new(std::env::current_exe().expect("test binary"))
        .args(["child", "--exact", "--nocapture", "--test-threads", "1"])
        .env(ROLE, role)
        .env(FLEET, fleet)
        .stdout(Stdio::piped())
        .spawn()
        .expect("child process")
}

fn closes<T: std::fmt::Debug>(mut f: impl FnMut() -> Result<Option<T>, TransportError>) {
    let t = Instant::now();
    loop {
        match f() {
            Err(TransportError::Closed) => return,
            Ok(None) if t.elapsed() < LONG => continue,
            other => panic!("expected Closed, got {other:?}"),
        }
    }
}

#[test]
fn a_child_process_publishes_weights_and_sends_experience() {
    let _turn = one_at_a_time();
    let fleet = format!("coadapt-test-{}-xproc", std::process::id());
    let cfg = cfg(fleet.clone());
    let mut rx = queue_receiver::<ExperienceChunk>(&cfg, "exp").expect("receiver");
    let mut sub = topic_subscriber::<Weights>(&cfg, "w").expect("subscriber");
    let mut child = spawn("publish", &fleet);
    let w = sub.wait_for(3, LONG).expect("wait").expect("version 3 from the child");
    assert_eq!(*w, weights(3, MIB));
    for i in 0..100 {
        assert_eq!(rx.recv_timeout(LONG).expect("receive"), Some(chunk(i)), "chunk {i}");
    }
    closes(|| rx.recv_timeout(Duration::from_millis(50)));
    assert!(child.wait().expect("child").success());
    closes(|| sub.wait_for(4, Duration::from_millis(50)));
}

/// Every node on the machine (alive or dead): its id and, while iceoryx2 still has its details,
/// its process id.
fn all_nodes() -> Vec<(u128, Option<u32>)> {
    let mut nodes = Vec::new();
    let listed = Node::<ipc_threadsafe::Service>::list(Config::global_config(), |state| {
        let (id, details) = match &state {
            NodeState::Alive(v) => (v.id().value(), v.details()),
            NodeState::Dead(v) => (v.id().value(), v.details()),
            _ => return CallbackProgression::Continue,
        };
        nodes.push((id, details.as_ref().and_then(|d| u32::try_from(d.process_id().value()).ok())));
        CallbackProgression::Continue
    });
    listed.expect("listing nodes");
    nodes
}

/// The ids of the nodes (alive or dead) that process `pid` created.
fn nodes_of(pid: u32) -> Vec<u128> {
    all_nodes().into_iter().filter(|&(_, p)| p == Some(pid)).map(|(id, _)| id).collect()
}

fn ready(child: &mut std::process::Child) {
    let stdout = child.stdout.take().expect("child stdout");
    let ready = BufReader::new(stdout).lines().map_while(Result::ok).any(|l| l.contains("READY"));
    assert!(ready, "the child never got ready");
}

/// The field's stuck node (seen on this project's machine): a process killed while iceoryx2
/// 0.10 writes a port's tag leaves a tag file still owner-writable, the mark of a file being
/// created, which iceoryx2's own listing skips; its cleanup removes the node's details, fails
/// on the non-empty directory with `InternalError`, and the dead node stayed on the machine,
/// reported by every run after. The child holds a subscriber; the test plants such a
/// half-written tag in its node's directory, as the kill would, then kills it.
#[test]
fn a_node_killed_while_opening_a_port_is_cleaned_up_all_the_same() {
    let _turn = one_at_a_time();
    let fleet = format!("coadapt-test-{}-orphan-tag", std::process::id());
    let mut child = spawn("idle", &fleet);
    ready(&mut child);
    let ids = nodes_of(child.id());
    assert_eq!(ids.len(), 1, "the child should have one node: {ids:?}");
    let nodes = std::path::PathBuf::from(Config::global_config().global.node_dir().to_string());
    let dir = nodes.join(ids[0].to_string());
    assert!(dir.is_dir(), "iceoryx2 keeps a node's details in {}", dir.display());
    let global = &Config::global_config().global;
    let port = 3_089_898_700_627_745_393_254_066_054_041u128 + u128::from(child.id());
    let tag = dir.join(format!("{}{port}{}", global.prefix, global.node.port_tag_suffix));
    std::fs::write(&tag, b"").expect("planting a half-written port tag");
    // Owner read-write is how iceoryx2 creates a tag (read-only once written).
    std::fs::set_permissions(&tag, std::os::unix::fs::PermissionsExt::from_mode(0o600)).expect("tag permissions");

    child.kill().expect("SIGKILL");
    child.wait().expect("reaped");
    let cleaned = cleanup_stale().expect("cleanup");
    assert!(cleaned >= 1, "the killed child's node was not cleaned up");
    // By id: a half-cleaned node has lost its details (and with them its process id).
    let listed = all_nodes().iter().any(|&(id, _)| id == ids[0]);
    assert!(!listed, "the killed child's node is still registered");
    assert!(!dir.exists(), "the dead node's directory is still there");
}

#[test]
fn a_killed_child_is_cleaned_up_and_a_new_publisher_takes_over() {
    let _turn = one_at_a_time();
    let fleet = format!("coadapt-test-{}-killed", std::process::id());
    let cfg = cfg(fleet.clone());
    let mut rx = queue_receiver::<ExperienceChunk>(&cfg, "exp").expect("receiver");
    let mut sub = topic_subscriber::<Weights>(&cfg, "w").expect("subscriber");
    let mut child = spawn("hang", &fleet);
    ready(&mut child);
    assert_eq!(rx.recv_timeout(LONG).expect("receive"), Some(chunk(0)));
    assert_eq!(sub.wait_for(1, LONG).expect("wait").expect("weights").version, 1);

    child.kill().expect("SIGKILL");
    child.wait().expect("reaped");
    let cleaned = cleanup_stale().expect("cleanup");
    assert!(cleaned >= 1, "the killed child's node was not cleaned up");
    closes(|| rx.recv_timeout(Duration::from_millis(50)));
    closes(|| sub.wait_for(2, Duration::from_millis(50)));

    let mut successor = topic_publisher::<Weights>(&cfg, "w").expect("a new publisher after cleanup");
    successor.publish(weights(5, 10)).expect("publish");
    assert_eq!(sub.wait_for(5, LONG).expect("wait").expect("weights").version, 5);
    // The child had two nodes (a sender's and a publisher's). Another cleaner (the receiver's
    // janitor in `closes`, the successor's node creation) may be part-way through one of them
    // when `cleanup_stale` passes it over, so give the cleaners a moment to finish.
    let child_nodes = || nodes_of(child.id()).len();
    let deadline = std::time::Instant::now() + LONG;
    let mut left = child_nodes();
    while left > 0 && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
        cleanup_stale().expect("cleanup");
        left = child_nodes();
    }
    assert_eq!(left, 0, "the killed child's nodes are still registered");
}
