//! Each action's success and failure cases, partial observability, and the
//! episode protocol (errors, termination, truncation).

use ctg_graph::{ActionId, CtgError, Environment, Vocabulary};
use env_collect::render::HAND_INSET_START;
use env_collect::{
    Action, Category, CollectConfig, CollectEnv, CollectInfo, CollectObservation, FRAME_DIM,
    Failure, Place, Receptacle, STATE_LEN, Target, Task, state_layout,
};
use image::RgbImage;

fn task(targets: &[(Category, Receptacle)]) -> Task {
    Task::new(
        targets
            .iter()
            .map(|&(category, receptacle)| Target {
                category,
                receptacle,
            })
            .collect(),
    )
    .unwrap()
}

fn two_targets() -> Task {
    task(&[
        (Category::Apple, Receptacle::Fridge),
        (Category::Mug, Receptacle::Cabinet),
    ])
}

fn env(task: Task) -> CollectEnv {
    CollectEnv::new(task, CollectConfig::default()).unwrap()
}

fn step(env: &mut CollectEnv, action: Action) -> (CollectObservation, CollectInfo) {
    let s = env.step(action.id()).unwrap();
    assert!(!s.terminated);
    (s.observation, s.info)
}

/// The search location where the object of `category` starts.
fn location_of(env: &CollectEnv, category: Category) -> usize {
    env.scene()
        .unwrap()
        .objects
        .iter()
        .find(|o| o.category == category)
        .unwrap()
        .location
}

/// Searches until the agent stands at location `target`.
fn go_to(env: &mut CollectEnv, target: usize) -> CollectObservation {
    for _ in 0..env.scene().unwrap().locations.len() {
        let (obs, info) = step(env, Action::Search);
        assert_eq!(info.failure, None, "search never fails");
        if env.place() == Some(Place::Location(target)) {
            return obs;
        }
    }
    panic!("location {target} never reached");
}

fn inset_is_empty(frame: &RgbImage) -> bool {
    // The inset's interior is a dark square when the hand is empty (noise
    // adds at most 6 per channel).
    (HAND_INSET_START + 1..63).all(|y| {
        (HAND_INSET_START + 1..63).all(|x| frame.get_pixel(x, y).0.iter().all(|&v| v < 40))
    })
}

fn non_inset_pixels(frame: &RgbImage) -> Vec<[u8; 3]> {
    frame
        .enumerate_pixels()
        .filter(|(x, y, _)| !(*x >= HAND_INSET_START && *y >= HAND_INSET_START))
        .map(|(_, _, p)| p.0)
        .collect()
}

#[test]
fn search_visits_every_location_in_order_cyclically() {
    let mut env = env(two_targets());
    let (obs, info) = env.reset(3).unwrap();
    assert_eq!(env.place(), Some(Place::Start));
    assert_eq!(obs.state[0], 1.0, "at_start");
    assert_eq!(info.action, None);
    let m = env.scene().unwrap().locations.len();
    assert_eq!(m, 2 + 3, "M = N + 3");
    for round in 0..2 {
        for i in 0..m {
            let (obs, info) = step(&mut env, Action::Search);
            assert_eq!(env.place(), Some(Place::Location(i)), "round {round}");
            assert_eq!(info.action, Some(Action::Search));
            assert_eq!(info.failure, None);
            assert_eq!(obs.state[1], 1.0, "at_search_location");
        }
    }
}

#[test]
fn pickup_succeeds_only_where_the_object_is_visible() {
    for seed in 0..20 {
        let mut env = env(two_targets());
        env.reset(seed).unwrap();
        let apple_at = location_of(&env, Category::Apple);

        // At the start nothing is visible.
        let (_, info) = step(&mut env, Action::Pickup(Category::Apple));
        assert_eq!(info.failure, Some(Failure::NotVisible(Category::Apple)));
        assert_eq!(env.held(), None);

        // Partial observability: the apple exists, but not here.
        let elsewhere = (apple_at + 1) % env.scene().unwrap().locations.len();
        let obs = go_to(&mut env, elsewhere);
        assert!(!env.visible().contains(&Category::Apple));
        assert_eq!(obs.state[state_index("visible_Apple")], 0.0);
        let (obs, info) = step(&mut env, Action::Pickup(Category::Apple));
        assert_eq!(info.failure, Some(Failure::NotVisible(Category::Apple)));
        assert_eq!(obs.state[state_index("last_action_failed")], 1.0);
        assert_eq!(env.held(), None);

        // Where it is, it is visible and can be picked up.
        let before = go_to(&mut env, apple_at);
        assert!(env.visible().contains(&Category::Apple));
        assert_eq!(before.state[state_index("visible_Apple")], 1.0);
        assert!(inset_is_empty(before.frame.as_ref().unwrap()));
        let (after, info) = step(&mut env, Action::Pickup(Category::Apple));
        assert_eq!(info.failure, None, "seed {seed}");
        assert_eq!(env.held(), Some(Category::Apple));
        assert!(!env.visible().contains(&Category::Apple));
        assert_eq!(after.state[state_index("visible_Apple")], 0.0);
        assert_eq!(after.state[state_index("held_Apple")], 1.0);
        assert_eq!(after.state[state_index("last_action_failed")], 0.0);
        // The frame shows it: the apple leaves the surface and fills the hand.
        let frame = after.frame.as_ref().unwrap();
        assert!(!inset_is_empty(frame));
        assert_ne!(
            non_inset_pixels(before.frame.as_ref().unwrap()),
            non_inset_pixels(frame)
        );
    }
}

#[test]
fn pickup_fails_with_full_hands() {
    // A distractor lying with the apple, or the other target, gives a second
    // visible object somewhere; find a seed where two objects share a place.
    let mut found = false;
    for seed in 0..200 {
        let mut env = env(two_targets());
        env.reset(seed).unwrap();
        let scene = env.scene().unwrap().clone();
        let Some((first, second)) = scene.objects.iter().enumerate().find_map(|(i, a)| {
            scene.objects[i + 1..]
                .iter()
                .find(|b| b.location == a.location)
                .map(|b| (a.clone(), b.clone()))
        }) else {
            continue;
        };
        go_to(&mut env, first.location);
        let (_, info) = step(&mut env, Action::Pickup(first.category));
        assert_eq!(info.failure, None);
        let (obs, info) = step(&mut env, Action::Pickup(second.category));
        assert_eq!(info.failure, Some(Failure::HandsFull));
        assert_eq!(env.held(), Some(first.category));
        assert!(env.visible().contains(&second.category));
        assert_eq!(obs.state[state_index("last_action_failed")], 1.0);
        found = true;
        break;
    }
    assert!(
        found,
        "no scene with two objects at one location in 200 seeds"
    );
}

#[test]
fn dropoff_puts_the_held_object_in_the_receptacle() {
    let mut env = env(two_targets());
    env.reset(5).unwrap();
    let mug_at = location_of(&env, Category::Mug);
    go_to(&mut env, mug_at);
    step(&mut env, Action::Pickup(Category::Mug));

    // The wrong receptacle: the mug is there, but not delivered.
    let (obs, info) = step(&mut env, Action::Dropoff(Receptacle::Sink));
    assert_eq!(info.failure, None);
    assert_eq!(env.place(), Some(Place::Receptacle(Receptacle::Sink)));
    assert_eq!(env.held(), None);
    assert_eq!(env.visible(), [Category::Mug]);
    assert_eq!(info.delivered, 0);
    assert!(!env.is_delivered(Category::Mug));
    assert_eq!(obs.state[state_index("at_Sink")], 1.0);
    assert_eq!(obs.state[state_index("visible_Mug")], 1.0);
    assert!(inset_is_empty(obs.frame.as_ref().unwrap()));

    // Objects in a receptacle can be picked up again, and then delivered.
    let (_, info) = step(&mut env, Action::Pickup(Category::Mug));
    assert_eq!(info.failure, None);
    assert!(env.visible().is_empty());
    let (_, info) = step(&mut env, Action::Dropoff(Receptacle::Cabinet));
    assert_eq!(info.failure, None);
    assert_eq!(info.delivered, 1);
    assert!(env.is_delivered(Category::Mug));
    assert!(!env.is_success(), "the apple is still out");

    let apple_at = location_of(&env, Category::Apple);
    go_to(&mut env, apple_at);
    step(&mut env, Action::Pickup(Category::Apple));
    let (_, info) = step(&mut env, Action::Dropoff(Receptacle::Fridge));
    assert_eq!((info.delivered, info.num_targets), (2, 2));
    assert!(env.is_success());
    let end = env.step(Vocabulary::END).unwrap();
    assert!(end.terminated && !end.truncated);
    assert_eq!(end.reward, 1.0);
}

#[test]
fn dropoff_with_empty_hands_goes_there_and_fails() {
    let mut env = env(two_targets());
    env.reset(1).unwrap();
    let (obs, info) = step(&mut env, Action::Dropoff(Receptacle::Microwave));
    assert_eq!(info.failure, Some(Failure::HandsEmpty));
    assert_eq!(env.place(), Some(Place::Receptacle(Receptacle::Microwave)));
    assert_eq!(obs.state[state_index("at_Microwave")], 1.0);
    assert_eq!(obs.state[state_index("last_action_failed")], 1.0);
    // Searching resumes the route from the beginning (no location visited).
    step(&mut env, Action::Search);
    assert_eq!(env.place(), Some(Place::Location(0)));
}

#[test]
fn search_resumes_after_a_dropoff() {
    let mut env = env(two_targets());
    env.reset(2).unwrap();
    step(&mut env, Action::Search);
    step(&mut env, Action::Search);
    step(&mut env, Action::Dropoff(Receptacle::Sink));
    step(&mut env, Action::Search);
    assert_eq!(env.place(), Some(Place::Location(2)));
}

#[test]
fn a_location_looks_the_same_whatever_happens_elsewhere() {
    // Partial observability: the view of a location depends only on what is
    // there (and on the hand).
    for seed in 0..10 {
        let mut env = env(two_targets());
        env.reset(seed).unwrap();
        let apple_at = location_of(&env, Category::Apple);
        let mug_at = location_of(&env, Category::Mug);
        let before = go_to(&mut env, mug_at);
        go_to(&mut env, apple_at);
        step(&mut env, Action::Pickup(Category::Apple));
        step(&mut env, Action::Dropoff(Receptacle::Fridge));
        let after = go_to(&mut env, mug_at);
        assert_eq!(
            non_inset_pixels(before.frame.as_ref().unwrap()),
            non_inset_pixels(after.frame.as_ref().unwrap())
        );
        assert_eq!(before.state, after.state);
    }
}

#[test]
fn end_terminates_and_an_incomplete_task_fails() {
    let mut env = env(two_targets());
    env.reset(0).unwrap();
    step(&mut env, Action::Search);
    let end = env.step(Vocabulary::END).unwrap();
    assert!(end.terminated && !end.truncated);
    assert_eq!(end.reward, 0.0);
    assert!(!env.is_success());
    assert_eq!(
        env.step(Action::Search.id()).unwrap_err(),
        CtgError::EpisodeOver
    );
}

#[test]
fn the_step_limit_truncates_and_success_counts_then() {
    let config = CollectConfig {
        max_steps: Some(4),
        ..CollectConfig::default()
    };
    let t = task(&[(Category::Egg, Receptacle::Sink)]);
    let mut env = CollectEnv::new(t, config).unwrap();
    assert_eq!(env.max_episode_steps(), 4);
    // Find a seed where the egg is at the first location: search, pickup,
    // dropoff, then one more action reaches the limit with the task done.
    let seed = (0..100)
        .find(|&s| {
            env.reset(s).unwrap();
            location_of(&env, Category::Egg) == 0
        })
        .expect("egg at location 0 for some seed");
    env.reset(seed).unwrap();
    for action in [
        Action::Search,
        Action::Pickup(Category::Egg),
        Action::Dropoff(Receptacle::Sink),
    ] {
        let s = env.step(action.id()).unwrap();
        assert!(!s.truncated && !s.terminated);
    }
    let last = env.step(Action::Search.id()).unwrap();
    assert!(last.truncated && !last.terminated);
    assert_eq!(last.reward, 1.0);
    assert!(env.is_success());
    assert_eq!(
        env.step(Action::Search.id()).unwrap_err(),
        CtgError::EpisodeOver
    );
    assert_eq!(
        CollectConfig::default_max_steps(5),
        36,
        "2 * (3N + 3) for N = 5"
    );
    assert!(
        CollectEnv::new(
            task(&[(Category::Egg, Receptacle::Sink)]),
            CollectConfig {
                max_steps: Some(0),
                ..CollectConfig::default()
            }
        )
        .is_err()
    );
}

#[test]
fn invalid_actions_are_errors_not_panics() {
    let mut env = env(two_targets());
    assert_eq!(
        env.step(Action::Search.id()).unwrap_err(),
        CtgError::NotReset
    );
    env.reset(0).unwrap();
    assert!(matches!(
        env.step(ActionId::new(16)),
        Err(CtgError::ActionOutOfRange { id: 16, len: 16 })
    ));
    assert!(matches!(
        env.step(Vocabulary::START),
        Err(CtgError::InvalidAction { .. })
    ));
    assert!(env.step(ActionId::new(usize::MAX)).is_err());
    // Still usable.
    step(&mut env, Action::Search);
    assert_eq!(env.steps_taken(), 1);
}

#[test]
fn rendering_off_gives_the_same_states_and_no_frames() {
    let t = two_targets();
    let mut on = env(t.clone());
    let mut off = CollectEnv::new(
        t,
        CollectConfig {
            render: false,
            ..CollectConfig::default()
        },
    )
    .unwrap();
    let (a, _) = on.reset(9).unwrap();
    let (b, _) = off.reset(9).unwrap();
    assert_eq!(a.state, b.state);
    assert!(a.frame.is_some() && b.frame.is_none());
    for action in [
        Action::Search,
        Action::Search,
        Action::Pickup(Category::Mug),
        Action::Dropoff(Receptacle::Cabinet),
    ] {
        let x = on.step(action.id()).unwrap();
        let y = off.step(action.id()).unwrap();
        assert_eq!(x.observation.state, y.observation.state);
        assert_eq!(x.info, y.info);
        assert_eq!(x.observation.state.len(), STATE_LEN);
        assert_eq!(x.observation.frame.unwrap().dimensions(), (64, 64));
    }
}

#[test]
fn the_environment_is_send_sync_clone_and_frames_featurise() {
    fn assert_send_sync_clone<T: Send + Sync + Clone>() {}
    assert_send_sync_clone::<CollectEnv>();
    assert_send_sync_clone::<CollectObservation>();

    let mut env = env(two_targets());
    let (obs, _) = env.reset(0).unwrap();
    let frame = obs.frame.as_ref().unwrap();
    let chw = obs.frame_chw().unwrap();
    assert_eq!(chw.len(), FRAME_DIM);
    assert!(chw.iter().all(|&v| (0.0..=1.0).contains(&v)));
    // CHW: channel c of pixel (x, y) sits at c * 64 * 64 + y * 64 + x.
    let (x, y) = (5u32, 9u32);
    for c in 0..3 {
        let v = chw[c * 64 * 64 + (y * 64 + x) as usize];
        assert_eq!((v * 255.0).round() as u8, frame.get_pixel(x, y).0[c]);
    }
    // A clone evolves independently.
    let mut copy = env.clone();
    step(&mut copy, Action::Search);
    assert_eq!(env.place(), Some(Place::Start));
    assert_eq!(copy.place(), Some(Place::Location(0)));
}

fn state_index(name: &str) -> usize {
    state_layout().iter().position(|n| n == name).unwrap()
}
