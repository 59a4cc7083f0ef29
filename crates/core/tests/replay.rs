#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use coadapt_core::{Batch, ReplayBuffer, ReplayError, Transition, rng};

fn t(v: f32) -> ([f32; 2], [f32; 1], [f32; 2]) {
    ([v, v], [v], [v + 0.5, v + 0.5])
}

fn push(buf: &mut ReplayBuffer, v: f32) {
    let (o, a, n) = t(v);
    buf.push(&Transition { obs: &o, action: &a, reward: v, next_obs: &n, terminated: v < 0.0 }).unwrap();
}

#[test]
fn ring_overwrites_the_oldest_and_keeps_fields_aligned() {
    let mut buf = ReplayBuffer::new(2, 1, 3);
    for v in 0..5 {
        push(&mut buf, v as f32);
    }
    assert_eq!(buf.len(), 3);
    let mut rewards: Vec<f32> = (0..3).map(|i| buf.get(i).reward).collect();
    rewards.sort_by(f32::total_cmp);
    assert_eq!(rewards, vec![2.0, 3.0, 4.0]);
    let mut b = Batch::new(64, 2, 1);
    buf.sample(&mut rng(1, 0), &mut b).unwrap();
    for r in 0..64 {
        let v = b.rew[r];
        assert_eq!(&b.obs[2 * r..2 * r + 2], &[v, v]);
        assert_eq!(b.act[r], v);
        assert_eq!(&b.next_obs[2 * r..2 * r + 2], &[v + 0.5, v + 0.5]);
    }
}

#[test]
fn mixed_batches_take_the_given_counts_from_each_buffer() {
    let mut pop = ReplayBuffer::new(2, 1, 100);
    let mut species = ReplayBuffer::new(2, 1, 100);
    for _ in 0..10 {
        push(&mut pop, 1.0);
        push(&mut species, 2.0);
    }
    let mut b = Batch::new(256, 2, 1);
    ReplayBuffer::sample_mixed(&[(&pop, 26), (&species, 230)], &mut rng(3, 0), &mut b).unwrap();
    assert_eq!(b.rew.iter().filter(|r| **r == 1.0).count(), 26);
    assert_eq!(b.rew.iter().filter(|r| **r == 2.0).count(), 230);
}

#[test]
fn malformed_transitions_are_rejected_and_nothing_is_stored() {
    let mut buf = ReplayBuffer::new(2, 1, 10);
    let bad_obs = [1.0, f32::NAN];
    let err = buf.push(&Transition { obs: &bad_obs, action: &[0.0], reward: 0.0, next_obs: &[0.0, 0.0], terminated: false });
    assert_eq!(err, Err(ReplayError::NonFinite { field: "obs", index: 1 }));
    let err = buf.push(&Transition { obs: &[0.0], action: &[0.0], reward: 0.0, next_obs: &[0.0, 0.0], terminated: false });
    assert_eq!(err, Err(ReplayError::Dim { field: "obs", expected: 2, got: 1 }));
    let err = buf.push(&Transition { obs: &[0.0, 0.0], action: &[0.0], reward: f32::INFINITY, next_obs: &[0.0, 0.0], terminated: false });
    assert!(matches!(err, Err(ReplayError::NonFinite { field: "reward", .. })));
    assert!(buf.is_empty());
    let mut b = Batch::new(4, 2, 1);
    assert_eq!(buf.sample(&mut rng(0, 0), &mut b), Err(ReplayError::Empty));
    push(&mut buf, -1.0);
    buf.clear();
    assert!(buf.is_empty());
}

fn rewards(b: &ReplayBuffer) -> Vec<f32> {
    let mut r: Vec<f32> = (0..b.len()).map(|i| b.get(i).reward).collect();
    r.sort_by(f32::total_cmp);
    r
}

fn push_reward(b: &mut ReplayBuffer, r: f32) {
    b.push(&Transition { obs: &[r, -r], action: &[r], reward: r, next_obs: &[r + 0.5, 0.0], terminated: false }).unwrap();
}

#[test]
fn pop_newest_removes_exactly_the_newest_rows_before_and_after_wrapping() {
    // Not wrapped: rows 0..6, drop the 3 newest.
    let mut b = ReplayBuffer::new(2, 1, 10);
    (0..6).for_each(|i| push_reward(&mut b, i as f32));
    b.pop_newest(3);
    assert_eq!(rewards(&b), [0.0, 1.0, 2.0]);
    push_reward(&mut b, 9.0);
    assert_eq!(rewards(&b), [0.0, 1.0, 2.0, 9.0], "the next push appends");
    // Wrapped: capacity 5, rows 0..8 leave 3..8 with 5, 6, 7 newest; drop 3 (crosses the seam).
    let mut b = ReplayBuffer::new(2, 1, 5);
    (0..8).for_each(|i| push_reward(&mut b, i as f32));
    b.pop_newest(3);
    assert_eq!(rewards(&b), [3.0, 4.0]);
    // Every field of each kept row moved together.
    for i in 0..b.len() {
        let t = b.get(i);
        assert_eq!((t.obs, t.action, t.next_obs[0]), (&[t.reward, -t.reward][..], &[t.reward][..], t.reward + 0.5));
    }
    (10..14).for_each(|i| push_reward(&mut b, i as f32));
    assert_eq!(b.len(), 5);
    let r = rewards(&b);
    assert_eq!(&r[1..], [10.0, 11.0, 12.0, 13.0], "full again: one of the two old rows is evicted, no new one");
    assert!(r[0] == 3.0 || r[0] == 4.0, "{r:?}");
    b.pop_newest(100);
    assert!(b.is_empty());
}
