//! Lists the iceoryx2 nodes on this machine and their state, then cleans up dead ones:
//! `cargo run --release -p coadapt-shm --example nodes`.

use iceoryx2::prelude::*;

fn main() {
    let listed = Node::<ipc_threadsafe::Service>::list(Config::global_config(), |state| {
        match &state {
            NodeState::Alive(v) => println!("alive  {:?}", v),
            NodeState::Dead(v) => println!("dead   {:?}", v),
            NodeState::Inaccessible(id) => println!("inaccessible {id:?}"),
            NodeState::Undefined(id) => println!("undefined {id:?}"),
        }
        CallbackProgression::Continue
    });
    if let Err(e) = listed {
        eprintln!("listing nodes failed: {e:?}");
    }
    match coadapt_shm::cleanup_stale() {
        Ok(n) => println!("cleaned up {n} dead nodes"),
        Err(e) => eprintln!("cleanup failed: {e}"),
    }
}
