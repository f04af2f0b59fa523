//! Unit tests of shapes, masks, attention, the GCN fixed point, the policy
//! and checkpoints.

use burn::module::{Module, Param};
use burn::tensor::activation::softmax;
use burn::tensor::{Bool, Device, Int, Tensor, TensorData};
use ctg_graph::symbolic::{SequenceObservation, SequenceTask};
use ctg_graph::{ActionId, Ctg, NodeSelection, Vocabulary};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::nn::{to_vec, to_vec_int};
use crate::*;

/// The CPU device under test: flex, or burn-ndarray when
/// `NTG_TEST_BACKEND=ndarray` in a build with the `ndarray` feature
/// (`NTG_TEST_BACKEND=ndarray cargo test -p ntg-model --features ndarray`:
/// the same tests on the other CPU backend). Asking for ndarray in a build
/// without the feature fails loudly rather than testing flex instead.
pub(crate) fn device() -> Device {
    match std::env::var("NTG_TEST_BACKEND").as_deref() {
        Ok("ndarray") => BackendKind::NdArray.device().expect(
            "NTG_TEST_BACKEND=ndarray needs the `ndarray` feature: cargo test -p ntg-model --features ndarray",
        ),
        Ok("flex") | Err(_) => BackendKind::Flex.device().unwrap(),
        Ok(other) => panic!("NTG_TEST_BACKEND={other}: expected flex or ndarray"),
    }
}

const N: usize = 7; // <start>, <end>, 5 actions
const D: usize = 9;

fn small_config(seed: u64) -> NtgConfig {
    let enc = EncoderConfig::State(StateEncoderConfig::new(D).with_hidden(16).with_out_dim(12));
    let mut c = NtgConfig::for_domain(N, enc);
    c.interpreter.hidden = 16;
    c.interpreter.token_embed = 8;
    c.gcn.hidden = 10;
    c.gcn.mlp_hidden = 8;
    c.edge.gcn_dim = 10;
    c.seed = seed;
    c
}

fn random_rows(rng: &mut ChaCha8Rng, rows: usize, dim: usize) -> Vec<Vec<f32>> {
    (0..rows)
        .map(|_| (0..dim).map(|_| rng.random_range(-1.0f32..1.0)).collect())
        .collect()
}

fn ids(v: &[usize]) -> Vec<ActionId> {
    v.iter().map(|&i| ActionId::new(i)).collect()
}

fn close(a: &[f32], b: &[f32], tol: f32) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

#[test]
fn encoders_map_rows_to_embeddings() {
    let dev = device();
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let cases = [
        (EncoderConfig::state(26), 26, 128),
        (
            EncoderConfig::Frame(
                FrameEncoderConfig::new()
                    .with_image_size(16)
                    .with_out_dim(32),
            ),
            3 * 16 * 16,
            32,
        ),
        (
            EncoderConfig::Frame(
                FrameEncoderConfig::new()
                    .with_image_size(16)
                    .with_hidden(Some(24))
                    .with_he_init(Some(true))
                    .with_centre_input(Some(true))
                    .with_out_dim(32),
            ),
            3 * 16 * 16,
            32,
        ),
        (
            EncoderConfig::Frame(
                FrameEncoderConfig::new()
                    .with_image_size(16)
                    .with_coord_channels(Some(true))
                    .with_out_dim(32),
            ),
            3 * 16 * 16,
            32,
        ),
        (
            EncoderConfig::Frame(
                FrameEncoderConfig::new()
                    .with_image_size(32)
                    .with_stem(Some(8))
                    .with_spatial_softmax(Some(true))
                    .with_out_dim(32),
            ),
            3 * 32 * 32,
            32,
        ),
        (
            EncoderConfig::Frame(
                FrameEncoderConfig::new()
                    .with_image_size(32)
                    .with_stem(Some(8))
                    .with_out_dim(32),
            ),
            3 * 32 * 32,
            32,
        ),
        (EncoderConfig::kinematics(3), 3 * 76, 128),
    ];
    for (cfg, d, h) in cases {
        assert_eq!(cfg.input_dim(), d);
        let enc = cfg.init(1, &dev).unwrap();
        let x = rows_tensor(&random_rows(&mut rng, 4, d), d, &dev).unwrap();
        assert_eq!(enc.forward(x).unwrap().dims(), [4, h]);
        let seq = Tensor::<3>::zeros([2, 5, d], &dev);
        assert_eq!(enc.forward_sequence(seq).unwrap().dims(), [2, 5, h]);
        // The wrong width is an error, not a panic.
        let bad = Tensor::<2>::zeros([4, d + 1], &dev);
        assert!(matches!(enc.forward(bad), Err(ModelError::Shape { .. })));
    }
    assert!(matches!(
        EncoderConfig::Frame(FrameEncoderConfig::new().with_image_size(20)).init(0, &dev),
        Err(ModelError::Config(_))
    ));
    // A stem halves the side once more: 24 is a multiple of 8, not of 16.
    assert!(matches!(
        EncoderConfig::Frame(
            FrameEncoderConfig::new()
                .with_image_size(24)
                .with_stem(Some(8))
        )
        .init(0, &dev),
        Err(ModelError::Config(_))
    ));
}

#[test]
fn he_initialised_centred_frame_encoder_keeps_its_activations_at_scale() {
    // PyTorch's default initialisation shrinks a ReLU stack's activations
    // about 2.4x per layer; He initialisation keeps them at one scale, so
    // the embedding of random frames is an order of magnitude larger.
    let dev = device();
    let rng = ChaCha8Rng::seed_from_u64(3);
    let d = 3 * 32 * 32;
    let x = || rows_tensor(&random_rows(&mut rng.clone(), 16, d), d, &dev).unwrap();
    let spread = |cfg: FrameEncoderConfig| {
        let enc = EncoderConfig::Frame(cfg.with_image_size(32))
            .init(1, &dev)
            .unwrap();
        let y = to_vec(enc.forward(x()).unwrap()).unwrap();
        let mean = y.iter().sum::<f32>() / y.len() as f32;
        (y.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / y.len() as f32).sqrt()
    };
    let default = spread(FrameEncoderConfig::new());
    let he = spread(
        FrameEncoderConfig::new()
            .with_he_init(Some(true))
            .with_centre_input(Some(true)),
    );
    assert!(he > 4.0 * default, "He {he} vs default {default}");
}

#[test]
fn same_seed_same_weights() {
    let dev = device();
    let a = NtgModel::new(small_config(5), &dev).unwrap();
    let b = NtgModel::new(small_config(5), &dev).unwrap();
    let c = NtgModel::new(small_config(6), &dev).unwrap();
    let w = |m: &NtgModel| to_vec(m.localizer.nodes.val()).unwrap();
    assert_eq!(w(&a), w(&b));
    assert_ne!(w(&a), w(&c));
    let g = |m: &NtgModel| to_vec(m.gcn.rnn.hidden.weight.val()).unwrap();
    assert_eq!(g(&a), g(&b));
}

fn demo_batch(dev: &Device, rng: &mut ChaCha8Rng) -> (DemoBatch, Vec<Vec<f32>>, Vec<ActionId>) {
    let long_obs = random_rows(rng, 6, D);
    let short_obs = random_rows(rng, 3, D);
    let long_actions = ids(&[2, 3, 4, 5, 6]);
    let short_actions = ids(&[4, 2]);
    let batch = DemoBatch::new(
        &[
            (&long_obs[..], &long_actions[..]),
            (&short_obs[..], &short_actions[..]),
        ],
        D,
        N,
        dev,
    )
    .unwrap();
    (batch, short_obs, short_actions)
}

#[test]
fn token_dropout_replaces_decoder_inputs_with_start() {
    let dev = device();
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let model = NtgModel::new(small_config(2), &dev).unwrap();
    let interp = &model.interpreter;
    let (batch, _, _) = demo_batch(&dev, &mut rng);
    let [b, l] = batch.targets.dims();
    let logits = |targets: Tensor<2, Int>, dropped: Option<Tensor<2, Bool>>| {
        let out = interp
            .forward_with_token_dropout(
                batch.frames.clone(),
                batch.frame_mask.clone(),
                targets,
                dropped,
            )
            .unwrap();
        to_vec(out.logits).unwrap()
    };
    // No dropout is plain teacher forcing.
    let plain = to_vec(
        interp
            .forward(
                batch.frames.clone(),
                batch.frame_mask.clone(),
                batch.targets.clone(),
            )
            .unwrap()
            .logits,
    )
    .unwrap();
    let none = Tensor::<2, Bool>::from_data(TensorData::new(vec![false; b * l], [b, l]), &dev);
    assert!(close(
        &plain,
        &logits(batch.targets.clone(), Some(none)),
        1e-6
    ));
    // Everything dropped: the decoder never sees the targets, so other
    // targets of the same length give the same logits; without dropout they
    // differ.
    let all = Tensor::<2, Bool>::from_data(TensorData::new(vec![true; b * l], [b, l]), &dev);
    let other = (batch.targets.clone() + 1).remainder_scalar(N as i64);
    assert!(close(
        &logits(batch.targets.clone(), Some(all.clone())),
        &logits(other.clone(), Some(all)),
        1e-6
    ));
    assert!(!close(&plain, &logits(other, None), 1e-3));
    // A mask of the wrong shape is an error, not a panic.
    let wrong = Tensor::<2, Bool>::from_data(TensorData::new(vec![true; b], [b, 1]), &dev);
    assert!(
        interp
            .forward_with_token_dropout(
                batch.frames.clone(),
                batch.frame_mask.clone(),
                batch.targets.clone(),
                Some(wrong)
            )
            .is_err()
    );
}

#[test]
fn deeper_state_encoder_has_the_same_interface() {
    let dev = device();
    let enc = EncoderConfig::State(
        StateEncoderConfig::new(D)
            .with_hidden(16)
            .with_out_dim(12)
            .with_hidden_layers(3),
    );
    let e = enc.init(0, &dev).unwrap();
    let Encoder::State(ref s) = e else {
        panic!("a state encoder")
    };
    assert_eq!(s.mid.len(), 2);
    let out = e.forward(Tensor::<2>::ones([4, D], &dev)).unwrap();
    assert_eq!(out.dims(), [4, 12]);
    let zero = EncoderConfig::State(StateEncoderConfig::new(D).with_hidden_layers(0));
    assert!(zero.init(0, &dev).is_err());
}

#[test]
fn pairwise_state_encoder_reads_relative_positions() {
    let dev = device();
    // D = 9: three objects' positions. With pairwise input, moving every
    // object by the same offset changes only the raw part of the input, so
    // an encoder whose raw-input weights are zero cannot tell the scenes
    // apart, while one without pairwise input (all weights raw) can.
    let config = StateEncoderConfig::new(D)
        .with_hidden(16)
        .with_out_dim(12)
        .with_pairwise_objects(3);
    let mut e = EncoderConfig::State(config).init(0, &dev).unwrap();
    assert_eq!(e.input_dim(), D);
    let Encoder::State(ref mut s) = e else {
        panic!("a state encoder")
    };
    assert_eq!(s.fc1.weight.dims(), [D + 27, 16]);
    let w = s.fc1.weight.val();
    let raw_zeroed = w
        .clone()
        .slice_assign([0..D, 0..16], Tensor::<2>::zeros([D, 16], &dev));
    s.fc1.weight = Param::from_tensor(raw_zeroed);
    let scene: Vec<f32> = (0..D).map(|i| i as f32 * 0.1).collect();
    let shifted: Vec<f32> = scene.iter().map(|v| v + 0.5).collect();
    let rows = |r: &Vec<f32>| Tensor::<2>::from_data(TensorData::new(r.clone(), [1, D]), &dev);
    let a = to_vec(e.forward(rows(&scene)).unwrap()).unwrap();
    let b = to_vec(e.forward(rows(&shifted)).unwrap()).unwrap();
    assert!(close(&a, &b, 1e-5));
    let c = to_vec(
        e.forward(rows(
            &scene
                .iter()
                .enumerate()
                .map(|(i, v)| if i == 0 { v + 0.5 } else { *v })
                .collect(),
        ))
        .unwrap(),
    )
    .unwrap();
    assert!(
        !close(&a, &c, 1e-4),
        "moving one object must change the encoding"
    );
    // More objects than the state holds is a configuration error.
    let too_many = StateEncoderConfig::new(D).with_pairwise_objects(4);
    assert!(EncoderConfig::State(too_many).init(0, &dev).is_err());
}

#[test]
fn interpreter_shapes_and_attention() {
    // The default interpreter; bidirectional GRU annotations with input
    // feeding, location-aware attention and a stateless decoder; the same
    // with local annotations instead of the GRUs.
    for (options, local) in [(None, None), (Some(true), None), (Some(true), Some(true))] {
        let mut config = small_config(1);
        config.interpreter.bidirectional = if local.is_some() { None } else { options };
        config.interpreter.input_feeding = options;
        config.interpreter.location_attention = options;
        config.interpreter.stateless_decoder = options;
        config.interpreter.local_annotations = local;
        let model = NtgModel::new(config, &device()).unwrap();
        assert_eq!(model.interpreter.local.is_some(), local.is_some());
        check_interpreter(&model.interpreter);
    }
    // Local annotations replace the GRU states: not both.
    let mut both = small_config(1).interpreter;
    both.bidirectional = Some(true);
    both.local_annotations = Some(true);
    assert!(matches!(
        both.init(0, &device()),
        Err(ModelError::Config(_))
    ));
}

/// Temporal pooling: the interpreter reads `⌈T/k⌉` averaged frames. A
/// padded demo scores as it does alone (padding stays out of every
/// window's mean), junk in the padding changes nothing, and greedy decoding
/// runs; a pool of 0 is refused.
#[test]
fn interpreter_frame_pool_reads_windows_of_frames() {
    let dev = device();
    let mut config = small_config(1).interpreter;
    config.frame_pool = Some(2);
    let interp = config.init(0, &dev).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (batch, short_obs, short_actions) = demo_batch(&dev, &mut rng);
    let out = interp
        .forward(
            batch.frames.clone(),
            batch.frame_mask.clone(),
            batch.targets.clone(),
        )
        .unwrap();
    // 6 frames in windows of 2: 3 attention columns; the short demo's 3
    // frames fill 2 windows, its padding the third, which gets no weight.
    assert_eq!(out.attention.dims(), [2, 6, 3]);
    let att = to_vec(out.attention.clone()).unwrap();
    for row in att[18..].chunks(3) {
        assert_eq!(row[2], 0.0, "padding window attended: {row:?}");
    }
    let junk = Tensor::<3>::ones([2, 6, D], &dev) * 100.0;
    let pad = (batch.frame_mask.clone().neg() + 1.0).unsqueeze_dim::<3>(2);
    let out_junk = interp
        .forward(
            batch.frames.clone() + junk * pad,
            batch.frame_mask.clone(),
            batch.targets.clone(),
        )
        .unwrap();
    let alone = DemoBatch::new(&[(&short_obs[..], &short_actions[..])], D, N, &dev).unwrap();
    let out_alone = interp
        .forward(alone.frames, alone.frame_mask, alone.targets)
        .unwrap();
    let [_, l, _] = out_alone.logits.dims();
    let short =
        |o: &InterpreterOutput| to_vec(o.logits.clone().narrow(0, 1, 1).narrow(1, 0, l)).unwrap();
    assert!(close(&short(&out), &short(&out_junk), 1e-5));
    assert!(close(
        &short(&out),
        &to_vec(out_alone.logits).unwrap(),
        1e-4
    ));
    assert!(interp.decode(&short_obs).unwrap().len() <= config.max_decode_len);
    // Pooling changes what the interpreter reads: not the unpooled output.
    let plain = small_config(1).interpreter.init(0, &dev).unwrap();
    let unpooled = plain
        .forward(batch.frames, batch.frame_mask, batch.targets)
        .unwrap();
    assert!(!close(
        &to_vec(out.logits).unwrap(),
        &to_vec(unpooled.logits).unwrap(),
        1e-4
    ));
    config.frame_pool = Some(0);
    assert!(matches!(config.init(0, &dev), Err(ModelError::Config(_))));
}

/// Aligned attention adds `−log(α_t(min(t + 1, T − 1)) + 0.1)` over the
/// real tokens to the token loss (the same weights as without it), needs
/// location-aware attention, and refuses a demo whose rows are not one
/// more than its actions; with rows given (a video's keyframes) it reads
/// those instead, pooled windows included, and checks them.
#[test]
fn aligned_attention_trains_one_row_per_token() {
    let dev = device();
    let stepping = |aligned: Option<bool>| {
        let mut c = small_config(4).interpreter;
        c.input_feeding = Some(true);
        c.location_attention = Some(true);
        c.stateless_decoder = Some(true);
        c.local_annotations = Some(true);
        c.aligned_attention = aligned;
        c
    };
    let plain = stepping(None).init(4, &dev).unwrap();
    let aligned = stepping(Some(true)).init(4, &dev).unwrap();
    assert!(aligned.aligned && !plain.aligned);
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let (batch, _, _) = demo_batch(&dev, &mut rng);
    let token_loss = to_vec(plain.loss(&batch).unwrap().loss).unwrap()[0];
    let both = to_vec(aligned.loss(&batch).unwrap().loss).unwrap()[0];
    // By hand: the long demo's 6 tokens on rows 1, 2, 3, 4, 5, 5, the short
    // one's 3 on rows 1, 2, 2.
    let att = to_vec(plain.attention(&batch).unwrap()).unwrap();
    let [_, l, t] = plain.attention(&batch).unwrap().dims();
    let mut nll = 0.0f32;
    for (i, rows) in [(0usize, vec![1usize, 2, 3, 4, 5, 5]), (1, vec![1, 2, 2])] {
        for (j, row) in rows.into_iter().enumerate() {
            nll -= (att[(i * l + j) * t + row] + ALIGNMENT_FLOOR).ln();
        }
    }
    let expected = token_loss + nll / 9.0;
    assert!(
        (both - expected).abs() <= 1e-4 * expected.abs().max(1.0),
        "{both} against {expected}"
    );
    assert!(nll > 0.0);
    // A demo of two rows for two actions (three tokens) is refused.
    let rows = random_rows(&mut rng, 2, D);
    let actions = ids(&[2, 3]);
    let bad = DemoBatch::new(&[(&rows[..], &actions[..])], D, N, &dev).unwrap();
    let err = aligned.loss(&bad).unwrap_err();
    assert!(
        matches!(&err, ModelError::Input(m) if m.contains("2 rows for 2 actions")),
        "{err}"
    );
    // Without location-aware attention: refused.
    let mut no_location = stepping(Some(true));
    no_location.location_attention = None;
    assert!(matches!(
        no_location.init(0, &dev),
        Err(ModelError::Config(_))
    ));
    // Rows given as the state rule would choose them: the same loss.
    let rule = vec![vec![1, 2, 3, 4, 5, 5], vec![1, 2, 2]];
    let given = batch.clone().with_aligned_rows(rule).unwrap();
    let same = to_vec(aligned.loss(&given).unwrap().loss).unwrap()[0];
    assert!((same - both).abs() <= 1e-6 * both.abs().max(1.0));
    // Rows given, frames pooled in twos: each token's target is the window
    // holding its row (the same weights as unpooled, other attention).
    let mut pooled_config = stepping(Some(true));
    pooled_config.frame_pool = Some(2);
    let pooled = pooled_config.init(4, &dev).unwrap();
    let plain_pooled = {
        let mut c = pooled_config.clone();
        c.aligned_attention = None;
        c.init(4, &dev).unwrap()
    };
    let rows = vec![vec![0, 1, 3, 3, 4, 5], vec![2, 2, 2]];
    let given = batch.clone().with_aligned_rows(rows.clone()).unwrap();
    let token_loss = to_vec(plain_pooled.loss(&given).unwrap().loss).unwrap()[0];
    let with = to_vec(pooled.loss(&given).unwrap().loss).unwrap()[0];
    let attention = plain_pooled.attention(&given).unwrap();
    let [_, l, t] = attention.dims();
    let att = to_vec(attention).unwrap();
    let mut nll = 0.0f32;
    for (i, rows) in rows.iter().enumerate() {
        for (j, &row) in rows.iter().enumerate() {
            nll -= (att[(i * l + j) * t + row / 2] + ALIGNMENT_FLOOR).ln();
        }
    }
    let expected = token_loss + nll / 9.0;
    assert!(
        (with - expected).abs() <= 1e-4 * expected.abs().max(1.0),
        "{with} against {expected}"
    );
    // Given rows are checked: one per token, inside the demo, in order.
    for (bad, words) in [
        (
            vec![vec![1, 2, 3, 4, 5], vec![1, 2, 2]],
            "5 rows given for its 6 tokens",
        ),
        (
            vec![vec![1, 2, 3, 4, 5, 6], vec![1, 2, 2]],
            "row 6 is past its end",
        ),
        (vec![vec![1, 2, 3, 4, 5, 5], vec![2, 1, 2]], "go backwards"),
        (
            vec![vec![1, 2, 3, 4, 5, 5]],
            "1 demos given for a batch of 2",
        ),
    ] {
        let err = batch.clone().with_aligned_rows(bad).unwrap_err();
        assert!(
            matches!(&err, ModelError::Input(m) if m.contains(words)),
            "{err}"
        );
    }
}

/// An older configuration without the interpreter options still loads,
/// with both off; the options do not change the default weights.
#[test]
fn interpreter_options_default_to_off() {
    let json = serde_json::to_value(small_config(2).interpreter).unwrap();
    let mut old = json.as_object().unwrap().clone();
    old.remove("bidirectional");
    old.remove("input_feeding");
    old.remove("location_attention");
    old.remove("stateless_decoder");
    old.remove("local_annotations");
    old.remove("frame_pool");
    let back: DemoInterpreterConfig = serde_json::from_value(old.into()).unwrap();
    assert_eq!(
        (
            back.bidirectional,
            back.input_feeding,
            back.location_attention,
            back.stateless_decoder
        ),
        (None, None, None, None)
    );
    let dev = device();
    let plain = back.init(3, &dev).unwrap();
    let both = back
        .clone()
        .with_bidirectional(Some(true))
        .with_input_feeding(Some(true))
        .with_location_attention(Some(true))
        .with_stateless_decoder(Some(true))
        .init(3, &dev)
        .unwrap();
    assert!(plain.bwd_gru.is_none() && both.bwd_gru.is_some());
    assert!(
        !plain.input_feeding && both.input_feeding && both.stateless && both.location.is_some()
    );
    // `Some(false)` is the same network as `None`, weight for weight.
    let off = back
        .clone()
        .with_bidirectional(Some(false))
        .with_input_feeding(Some(false))
        .with_location_attention(Some(false))
        .with_stateless_decoder(Some(false))
        .init(3, &dev)
        .unwrap();
    let w = |i: &DemoInterpreter| {
        [
            i.out.weight.val(),
            i.attn.weight.val(),
            i.dec_gru.input.weight.val(),
        ]
        .map(|t| to_vec(t).unwrap())
    };
    assert_eq!(w(&plain), w(&off));
    assert!(off.bwd_gru.is_none() && !off.input_feeding);
    assert!(off.location.is_none() && !off.stateless);
}

fn check_interpreter(interp: &DemoInterpreter) {
    let dev = device();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (batch, short_obs, short_actions) = demo_batch(&dev, &mut rng);
    assert_eq!(batch.frames.dims(), [2, 6, D]);
    assert_eq!(batch.targets.dims(), [2, 6]); // 5 actions + <end>
    let out = interp
        .forward(
            batch.frames.clone(),
            batch.frame_mask.clone(),
            batch.targets.clone(),
        )
        .unwrap();
    assert_eq!(out.logits.dims(), [2, 6, N]);
    assert_eq!(out.attention.dims(), [2, 6, 6]);

    // Every attention row sums to 1, and the short demo gives its three
    // padding frames no weight.
    let att = to_vec(out.attention).unwrap();
    for row in att.chunks(6) {
        assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{row:?}");
    }
    for row in att[36..].chunks(6) {
        assert!(
            row[3..].iter().all(|&w| w == 0.0),
            "padding attended: {row:?}"
        );
        assert!(row[..3].iter().all(|&w| w > 0.0));
    }

    // Padding is ignored: junk in the padded frames changes nothing, and the
    // short demo scores the same in the batch as alone.
    let junk = Tensor::<3>::ones([2, 6, D], &dev) * 100.0;
    let pad = (batch.frame_mask.clone().neg() + 1.0).unsqueeze_dim::<3>(2);
    let frames_junk = batch.frames.clone() + junk * pad;
    let out_junk = interp
        .forward(frames_junk, batch.frame_mask.clone(), batch.targets.clone())
        .unwrap();
    let alone = DemoBatch::new(&[(&short_obs[..], &short_actions[..])], D, N, &dev).unwrap();
    let out_alone = interp
        .forward(alone.frames, alone.frame_mask, alone.targets)
        .unwrap();
    let in_batch = to_vec(out_junk.logits.narrow(0, 1, 1).narrow(1, 0, 3)).unwrap();
    assert!(close(&in_batch, &to_vec(out_alone.logits).unwrap(), 1e-4));

    let loss = interp.loss(&batch).unwrap();
    assert_eq!(loss.loss.dims(), [1]);
    assert!((0.0..=1.0).contains(&loss.accuracy));

    // Greedy decoding never emits <start> and stops by max_decode_len.
    let decoded = interp.decode(&short_obs).unwrap();
    assert!(decoded.len() <= interp.max_decode_len);
    assert!(!decoded.contains(&Vocabulary::START) && !decoded.contains(&Vocabulary::END));
    let batch_decoded = interp
        .decode_batch(&[&short_obs[..], &short_obs[..]])
        .unwrap();
    assert_eq!(batch_decoded[0], decoded);
    assert_eq!(batch_decoded[1], decoded);
}

#[test]
fn demo_batch_rejects_bad_input() {
    let dev = device();
    let obs = vec![vec![0.0; D]; 3];
    let bad_rows = [vec![0.0; D], vec![0.0; D - 1]];
    let a = ids(&[2, 3]);
    assert!(matches!(
        DemoBatch::new(&[(&bad_rows[..], &a[..])], D, N, &dev),
        Err(ModelError::Shape { .. })
    ));
    assert!(DemoBatch::new(&[(&obs[..], &ids(&[2, 9])[..])], D, N, &dev).is_err());
    assert!(DemoBatch::new(&[(&obs[..], &ids(&[0])[..])], D, N, &dev).is_err());
    let empty: &[(&[Vec<f32>], &[ActionId])] = &[];
    assert!(DemoBatch::new(empty, D, N, &dev).is_err());
}

fn set_constant(mlp: PairMlp, value: f32, dev: &Device) -> PairMlp {
    let m = mlp.out.weight.dims()[0];
    PairMlp {
        out: burn::nn::Linear {
            weight: Param::from_data(TensorData::new(vec![0.0f32; m], [m, 1]), dev),
            bias: Some(Param::from_data(TensorData::new(vec![value], [1]), dev)),
        },
        ..mlp
    }
}

#[test]
fn gcn_shapes_and_fixed_point() {
    let dev = device();
    let model = NtgModel::new(small_config(2), &dev).unwrap();
    let g1 = Ctg::from_path(N, &ids(&[2, 3, 4])).unwrap();
    let g2 = Ctg::from_path(N, &ids(&[5, 2, 6, 2])).unwrap();
    let adj = adjacency_tensor(&[&g1, &g2], N, &dev).unwrap();
    let out = model.gcn.forward(adj.clone()).unwrap();
    assert_eq!(out.adjacency.dims(), [2, N, N]);
    assert_eq!(out.embeddings.dims(), [2, N, 10]);
    let probs = to_vec(out.adjacency.clone()).unwrap();
    assert!(probs.iter().all(|p| (0.0..=1.0).contains(p)));
    // Nothing into <start>, nothing out of <end>.
    for b in 0..2 {
        for i in 0..N {
            assert_eq!(probs[b * N * N + i * N], 0.0);
            assert_eq!(probs[b * N * N + N + i], 0.0);
        }
    }
    let loss = model.gcn.loss(&out, adj.clone()).unwrap();
    assert!(crate::nn::scalar(loss).unwrap() > 0.0);
    assert!(
        model
            .gcn
            .forward(Tensor::zeros([1, N + 1, N + 1], &dev))
            .is_err()
    );

    // f_set ≡ 0 and f_reset ≡ 1: every iteration keeps C as it is.
    let mut gcn = model.gcn.clone();
    gcn.f_set = set_constant(gcn.f_set, -100.0, &dev); // σ(−100) ≈ 0
    gcn.f_reset = set_constant(gcn.f_reset, 100.0, &dev); // σ(100) = 1
    gcn.iterations = 5;
    let fixed = gcn.forward(adj.clone()).unwrap();
    assert!(close(
        &to_vec(fixed.adjacency).unwrap(),
        &to_vec(adj).unwrap(),
        1e-6
    ));

    let counts = EdgeCounts::count(&[0.9, 0.2, 0.7, 0.0], &[1.0, 1.0, 0.0, 0.0], 0.5).unwrap();
    assert_eq!(
        (
            counts.true_positives,
            counts.false_positives,
            counts.false_negatives
        ),
        (1, 1, 1)
    );
    assert!((counts.f1() - 0.5).abs() < 1e-6);
}

#[test]
fn masked_edge_logits_never_choose_a_non_successor() {
    let dev = device();
    let model = NtgModel::new(small_config(3), &dev).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let b = 64;
    let obs = rows_tensor(&random_rows(&mut rng, b, D), D, &dev).unwrap();
    let nodes: Vec<i64> = (0..b).map(|_| rng.random_range(0..N as i64)).collect();
    let mut mask = vec![false; b * N];
    for row in mask.chunks_mut(N) {
        // One to three successors per row, at random.
        for _ in 0..rng.random_range(1..4) {
            row[rng.random_range(0..N)] = true;
        }
    }
    let masks = Tensor::<2, Bool>::from_data(TensorData::new(mask.clone(), [b, N]), &dev);
    let node_ids = Tensor::<1, Int>::from_data(TensorData::new(nodes, [b]), &dev);
    let ne_gcn = model.gcn.initial_embeddings(b);
    let logits = model
        .edges
        .forward(
            obs,
            node_ids,
            ne_gcn,
            model.localizer.node_embeddings(),
            masks,
            None,
        )
        .unwrap();
    assert_eq!(logits.dims(), [b, N]);
    let choice = to_vec_int(logits.clone().argmax(1).reshape([b])).unwrap();
    let probs = to_vec(softmax(logits, 1)).unwrap();
    for r in 0..b {
        assert!(
            mask[r * N + choice[r] as usize],
            "row {r} chose a non-successor"
        );
        for a in 0..N {
            if !mask[r * N + a] {
                assert_eq!(probs[r * N + a], 0.0);
            }
        }
    }
}

#[test]
fn localizer_shapes_and_loss() {
    let dev = device();
    let model = NtgModel::new(small_config(4), &dev).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let obs = rows_tensor(&random_rows(&mut rng, 5, D), D, &dev).unwrap();
    let logits = model.localizer.forward(obs).unwrap();
    assert_eq!(logits.dims(), [5, N]);
    let labels = ids_tensor(&ids(&[0, 2, 3, 4, 6]), N, &dev).unwrap();
    let out = model.localizer.loss(logits.clone(), labels).unwrap();
    // Untrained: the loss is about ln N.
    let l = crate::nn::scalar(out.loss).unwrap();
    assert!(l > 0.5 && l < 5.0, "{l}");
    assert!(ids_tensor(&ids(&[N]), N, &dev).is_err());
    let short = ids_tensor(&ids(&[0, 1]), N, &dev).unwrap();
    assert!(model.localizer.loss(logits, short).is_err());
}

#[test]
fn successor_mask_checks_targets() {
    let dev = device();
    let g = Ctg::from_path(N, &ids(&[2, 3])).unwrap();
    let m = successor_mask(&[&g, &g], &ids(&[0, 2]), Some(&ids(&[2, 3])), N, &dev).unwrap();
    let v = to_vec(m.float()).unwrap();
    assert_eq!(v.iter().sum::<f32>(), 2.0);
    assert_eq!(v[2], 1.0);
    assert_eq!(v[N + 3], 1.0);
    assert!(successor_mask(&[&g], &ids(&[0]), Some(&ids(&[3])), N, &dev).is_err());
}

fn one_hot_row(i: usize) -> Vec<f32> {
    let mut v = vec![0.0; D];
    v[i] = 1.0;
    v
}

#[test]
fn policy_runs_end_to_end_and_log_probs_agree() {
    let dev = device();
    let vocab = Vocabulary::new(["a", "b", "c", "d", "e"]).unwrap();
    let model = NtgModel::new(small_config(7), &dev).unwrap();
    let demo: Vec<Vec<f32>> = (0..4).map(one_hot_row).collect();
    let policy = NtgPolicy::from_demo(&model, &demo, &vocab).unwrap();
    assert!(policy.initial_graph().is_subgraph_of(policy.graph()));
    assert!(policy.graph().contains_path(policy.demo_actions()));

    let obs = one_hot_row(2);
    let dist = policy.action_distribution(&obs).unwrap();
    let total: f32 = dist.probabilities().iter().sum();
    assert!((total - 1.0).abs() < 1e-5);
    let logp = policy.log_probabilities(&obs).unwrap();
    assert_eq!(logp.len(), N);
    for (a, &l) in logp.iter().enumerate() {
        let p = dist.probability(ActionId::new(a));
        if p > 1e-6 {
            assert!((l.exp() - p).abs() < 1e-4, "action {a}: {} vs {p}", l.exp());
        } else {
            assert!(l < -10.0);
        }
    }
    // Node and edge scores are probabilities.
    let nodes = policy.node_probabilities(&obs).unwrap();
    assert!((nodes.iter().sum::<f32>() - 1.0).abs() < 1e-5);
    let edges = policy.edge_probabilities_for(policy.graph(), &obs).unwrap();
    for (from, row) in edges.chunks(N).enumerate() {
        let s: f32 = row.iter().sum();
        let has = !policy.graph().successors(ActionId::new(from)).is_empty();
        assert!(if has {
            (s - 1.0).abs() < 1e-5
        } else {
            s == 0.0
        });
    }
    // A wrong-length observation is an error, not a panic.
    assert!(policy.action_distribution(&[0.0; 3]).is_err());

    // One full episode in the symbolic environment through the executor.
    let target = vocab.parse_sequence("a b").unwrap();
    let mut env = SequenceTask::new(vocab.clone(), target);
    let mapped = policy.mapped(|o: &SequenceObservation| one_hot_row(o.last.index()));
    let rollout = policy
        .executor()
        .run(&mut env, &mut &mapped, &mut &mapped, 0)
        .unwrap();
    assert!(!rollout.steps.is_empty());
    for s in &rollout.steps {
        assert!(s.probability > 0.0);
    }
    assert!(NtgPolicy::from_demo(&model, &demo, &Vocabulary::new(["a"]).unwrap()).is_err());
}

#[test]
fn argmax_node_selection_log_probs_agree() {
    let dev = device();
    let mut cfg = small_config(8);
    cfg.node_selection = NodeSelection::ArgMax;
    let model = NtgModel::new(cfg, &dev).unwrap();
    let policy = NtgPolicy::from_actions(&model, &ids(&[2, 3, 2, 4])).unwrap();
    for i in 0..D {
        let obs = one_hot_row(i);
        let dist = policy.action_distribution(&obs).unwrap();
        let logp = policy.log_probabilities(&obs).unwrap();
        for (a, &l) in logp.iter().enumerate() {
            let p = dist.probability(ActionId::new(a));
            assert!((l.exp() - p).abs() < 1e-4);
        }
    }
}

#[test]
fn ablations_replace_components() {
    let dev = device();
    let vocab = Vocabulary::new(["a", "b", "c", "d", "e"]).unwrap();
    let demo: Vec<Vec<f32>> = (0..4).map(one_hot_row).collect();
    let obs = one_hot_row(1);

    let mut cfg = small_config(9);
    cfg.ablation.demo_interpreter = false;
    cfg.ablation.gcn = false;
    let policy = NtgPolicy::from_demo(&NtgModel::new(cfg, &dev).unwrap(), &demo, &vocab).unwrap();
    assert_eq!(policy.graph(), &Ctg::fully_connected(N));
    assert!(policy.demo_actions().is_empty());

    let mut cfg = small_config(9);
    cfg.ablation.gcn = false;
    let model = NtgModel::new(cfg, &dev).unwrap();
    let path = ids(&[2, 4, 3]);
    let policy = NtgPolicy::from_actions(&model, &path).unwrap();
    assert_eq!(policy.graph(), &Ctg::from_path(N, &path).unwrap());

    let mut cfg = small_config(9);
    cfg.ablation.node_localizer = false;
    let policy = NtgPolicy::from_demo(&NtgModel::new(cfg, &dev).unwrap(), &demo, &vocab).unwrap();
    let nodes = policy.node_probabilities(&obs).unwrap();
    assert!(nodes.iter().all(|&p| (p - 1.0 / N as f32).abs() < 1e-6));

    let mut cfg = small_config(9);
    cfg.ablation.edge_classifier = false;
    let policy = NtgPolicy::from_demo(&NtgModel::new(cfg, &dev).unwrap(), &demo, &vocab).unwrap();
    let edges = policy.edge_probabilities_for(policy.graph(), &obs).unwrap();
    for (from, row) in edges.chunks(N).enumerate() {
        let succ = policy.graph().successors(ActionId::new(from));
        for (a, &p) in row.iter().enumerate() {
            let expected = if succ.contains(&ActionId::new(a)) {
                1.0 / succ.len() as f32
            } else {
                0.0
            };
            assert!((p - expected).abs() < 1e-6);
        }
    }
}

#[test]
fn the_executed_node_replaces_the_localizer_with_the_last_action_taken() {
    let dev = device();
    let mut cfg = small_config(9);
    cfg.ablation.executed_node = Some(true);
    let model = NtgModel::new(cfg, &dev).unwrap();
    let path = ids(&[2, 4, 3]);
    let policy = NtgPolicy::from_actions(&model, &path).unwrap();
    assert!(policy.uses_executed_node());
    let obs = one_hot_row(1);
    let one_hot_at = |node: usize| {
        let nodes = policy.node_probabilities(&obs).unwrap();
        nodes
            .iter()
            .enumerate()
            .all(|(i, &p)| p == if i == node { 1.0 } else { 0.0 })
    };
    // Before any action the agent is at <start>.
    policy.set_executed(&[]);
    assert!(one_hot_at(Vocabulary::START.index()));
    // The same observation, another record: the node follows the record,
    // and π is that node's edge row.
    policy.set_executed(&ids(&[2, 4]));
    assert!(one_hot_at(4));
    let pi = policy.action_distribution(&obs).unwrap();
    let edges = policy
        .edge_probabilities_for(policy.execution_graph(), &obs)
        .unwrap();
    for (a, &p) in edges[4 * N..5 * N].iter().enumerate() {
        assert!((pi.probability(ActionId::new(a)) - p).abs() < 1e-6);
    }
    let logp = policy.log_probabilities(&obs).unwrap();
    for (a, &l) in logp.iter().enumerate() {
        assert!((l.exp() - pi.probability(ActionId::new(a))).abs() < 1e-5);
    }
    // Models saved before the switch existed load with it off.
    let mut json: serde_json::Value = serde_json::to_value(small_config(9)).unwrap();
    json["ablation"]
        .as_object_mut()
        .unwrap()
        .remove("executed_node");
    let old: NtgConfig = serde_json::from_value(json).unwrap();
    assert_eq!(old.ablation.executed_node, None);
}

#[test]
fn end_after_demo_blocks_end_while_a_demo_action_is_pending() {
    let dev = device();
    let path = ids(&[2, 4, 3]);
    let end = Vocabulary::END;
    // Every edge kept (threshold 0), so `<end>` follows every node.
    let policy_with = |rule: bool| {
        let mut cfg = small_config(9);
        cfg.ablation.executed_node = Some(true);
        cfg.ablation.end_after_demo = rule.then_some(true);
        cfg.edge_threshold = 0.0;
        let model = NtgModel::new(cfg, &dev).unwrap();
        NtgPolicy::from_actions(&model, &path).unwrap()
    };
    let obs = one_hot_row(1);
    let with = policy_with(true);
    assert!(with.ends_after_demo());
    assert!(with.execution_graph().has_edge(ActionId::new(4), end));
    // 3 is pending: no `<end>`, and π still sums to one.
    with.set_executed(&ids(&[2, 4]));
    let pi = with.action_distribution(&obs).unwrap();
    assert_eq!(pi.probability(end), 0.0);
    let total: f32 = (0..N).map(|a| pi.probability(ActionId::new(a))).sum();
    assert!((total - 1.0).abs() < 1e-5, "{total}");
    assert_eq!(
        with.log_probabilities(&obs).unwrap()[end.index()],
        f32::NEG_INFINITY
    );
    // Every demo action executed: `<end>` is allowed again.
    with.set_executed(&ids(&[2, 4, 3]));
    assert!(with.action_distribution(&obs).unwrap().probability(end) > 0.0);
    // Without the rule `<end>` is open while 3 is pending.
    let without = policy_with(false);
    assert!(!without.ends_after_demo());
    without.set_executed(&ids(&[2, 4]));
    assert!(without.action_distribution(&obs).unwrap().probability(end) > 0.0);
    // Models saved before the switch existed load with it off.
    let mut json: serde_json::Value = serde_json::to_value(small_config(9)).unwrap();
    json["ablation"]
        .as_object_mut()
        .unwrap()
        .remove("end_after_demo");
    let old: NtgConfig = serde_json::from_value(json).unwrap();
    assert_eq!(old.ablation.end_after_demo, None);
}

#[test]
fn the_last_localizer_reading_is_the_node_distribution_of_the_last_observation() {
    let dev = device();
    let model = NtgModel::new(small_config(9), &dev).unwrap();
    let policy = NtgPolicy::from_actions(&model, &ids(&[2, 4, 3])).unwrap();
    // Nothing scored yet.
    assert_eq!(policy.last_localizer_probabilities(), None);
    let (a, b) = (one_hot_row(1), one_hot_row(2));
    policy.action_distribution(&a).unwrap();
    policy.action_distribution(&b).unwrap();
    let last = policy.last_localizer_probabilities().unwrap();
    assert_eq!(last, policy.node_probabilities(&b).unwrap());
    assert_ne!(last, policy.node_probabilities(&a).unwrap());
    // With the node taken from the record, the localizer read nothing.
    let mut cfg = small_config(9);
    cfg.ablation.executed_node = Some(true);
    let model = NtgModel::new(cfg, &dev).unwrap();
    let policy = NtgPolicy::from_actions(&model, &ids(&[2, 4, 3])).unwrap();
    policy.set_executed(&ids(&[2]));
    policy.action_distribution(&a).unwrap();
    assert_eq!(policy.last_localizer_probabilities(), None);
}

#[test]
fn a_localizer_with_temporal_context_reads_the_change_since_the_previous_observation() {
    let dev = device();
    let mut cfg = small_config(9);
    let EncoderConfig::State(state) = &mut cfg.localizer.encoder else {
        panic!("small_config has state encoders");
    };
    state.input_dim *= 2;
    cfg.localizer.previous_observation = Some(true);
    let model = NtgModel::new(cfg.clone(), &dev).unwrap();
    assert_eq!(model.obs_dim(), D);
    let policy = NtgPolicy::from_actions(&model, &ids(&[2, 4, 3])).unwrap();
    assert!(policy.reads_previous_observation());
    let (a, b) = (one_hot_row(1), one_hot_row(2));
    // The first decision reads the observation as its own previous one.
    policy.set_previous_observation(None);
    let first = policy.node_probabilities(&b).unwrap();
    policy.set_previous_observation(Some(&b));
    assert_eq!(policy.node_probabilities(&b).unwrap(), first);
    // Another previous observation, another reading of the same one.
    policy.set_previous_observation(Some(&a));
    let after_a = policy.node_probabilities(&b).unwrap();
    assert_ne!(after_a, first);
    // The same as the localizer's logits on [o, o - o_prev].
    let input = NodeLocalizer::in_context(
        rows_tensor(&[b.as_slice()], D, &dev).unwrap(),
        rows_tensor(&[a.as_slice()], D, &dev).unwrap(),
    )
    .unwrap();
    let logits = to_vec(model.valid().localizer.forward(input).unwrap()).unwrap();
    let z: f32 = logits.iter().map(|l| l.exp()).sum();
    for (p, l) in after_a.iter().zip(&logits) {
        assert!((p - l.exp() / z).abs() < 1e-5);
    }
    // Observations of another length, and an encoder with pairwise
    // features, are refused.
    assert!(
        NodeLocalizer::in_context(
            rows_tensor(&[b.as_slice()], D, &dev).unwrap(),
            Tensor::zeros([1, D + 1], &dev),
        )
        .is_err()
    );
    let mut pairwise = cfg;
    if let EncoderConfig::State(state) = &mut pairwise.localizer.encoder {
        state.pairwise_objects = 2;
    }
    let err = pairwise.validate().unwrap_err().to_string();
    assert!(err.contains("previous observation"), "{err}");
}

#[test]
fn a_model_folder_with_safetensors_weights_loads_the_same_model() {
    let dev = device();
    let dir = tempfile::tempdir().unwrap();
    let model = NtgModel::new(small_config(12), &dev).unwrap();
    model.save(dir.path()).unwrap();
    let file = dir.path().join(export::SAFETENSORS_WEIGHTS_FILE);
    let tensors =
        export::save_safetensors(&model, &file, &std::collections::BTreeMap::new()).unwrap();
    assert!(file.with_extension("safetensors.sha256").is_file());
    // Readable by others, as the project's other files are.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&file).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o644, "{mode:o}");
    }
    // Written once: an existing file is refused.
    assert!(export::save_safetensors(&model, &file, &Default::default()).is_err());
    // PyTorch's layout: a Linear weight transposed, a bare table not.
    let out = tensors
        .iter()
        .find(|t| t.name == "interpreter.out.weight")
        .unwrap();
    let [d_in, d_out] = model.interpreter.out.weight.val().dims();
    assert!(out.transposed && out.module == "Linear" && out.shape == [d_out, d_in]);
    let nodes = tensors
        .iter()
        .find(|t| t.name == "localizer.nodes")
        .unwrap();
    assert!(!nodes.transposed);

    std::fs::remove_file(dir.path().join(WEIGHTS_FILE)).unwrap();
    let loaded = NtgModel::load(dir.path(), &dev).unwrap();
    let values = |m: &NtgModel| {
        [
            to_vec(m.interpreter.out.weight.val()).unwrap(),
            to_vec(m.localizer.nodes.val()).unwrap(),
            to_vec(m.gcn.rnn.hidden.weight.val()).unwrap(),
            to_vec(m.edges.w.weight.val()).unwrap(),
        ]
    };
    assert_eq!(values(&loaded), values(&model));

    // The file of another network is refused, naming it.
    let other = tempfile::tempdir().unwrap();
    let mut config = small_config(12);
    config.interpreter.hidden += 1;
    let bigger = NtgModel::new(config, &dev).unwrap();
    bigger.save(other.path()).unwrap();
    std::fs::remove_file(other.path().join(WEIGHTS_FILE)).unwrap();
    std::fs::copy(&file, other.path().join(export::SAFETENSORS_WEIGHTS_FILE)).unwrap();
    match NtgModel::load(other.path(), &dev) {
        Err(ModelError::File { path, .. }) => {
            assert!(path.ends_with(export::SAFETENSORS_WEIGHTS_FILE))
        }
        other => panic!("expected a file error, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn save_then_load_gives_identical_outputs() {
    let dev = device();
    let dir = tempfile::tempdir().unwrap();
    let model = NtgModel::new(small_config(11), &dev).unwrap();
    model.save(dir.path()).unwrap();
    let loaded = NtgModel::load(dir.path(), &dev).unwrap();
    assert_eq!(
        serde_json::to_string(loaded.config()).unwrap(),
        serde_json::to_string(model.config()).unwrap()
    );
    let demo: Vec<Vec<f32>> = (0..5).map(one_hot_row).collect();
    let vocab = Vocabulary::new(["a", "b", "c", "d", "e"]).unwrap();
    let p1 = NtgPolicy::from_demo(&model, &demo, &vocab).unwrap();
    let p2 = NtgPolicy::from_demo(&loaded, &demo, &vocab).unwrap();
    assert_eq!(p1.demo_actions(), p2.demo_actions());
    assert_eq!(p1.edge_probabilities(), p2.edge_probabilities());
    for i in 0..D {
        let obs = one_hot_row(i);
        assert_eq!(
            p1.log_probabilities(&obs).unwrap(),
            p2.log_probabilities(&obs).unwrap()
        );
    }
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let (batch, _, _) = demo_batch(&dev, &mut rng);
    let l1 = to_vec(model.interpreter.loss(&batch).unwrap().loss).unwrap();
    let l2 = to_vec(loaded.interpreter.loss(&batch).unwrap().loss).unwrap();
    assert_eq!(l1, l2);

    // A corrupt weights file, a corrupt config and a missing directory are
    // errors naming the file.
    std::fs::write(dir.path().join(WEIGHTS_FILE), b"not a burnpack").unwrap();
    match NtgModel::load(dir.path(), &dev) {
        Err(ModelError::File { path, .. }) => assert!(path.ends_with(WEIGHTS_FILE)),
        other => panic!("expected a file error, got {other:?}"),
    }
    std::fs::write(dir.path().join(CONFIG_FILE), b"{ \"num_nodes\": ").unwrap();
    match NtgModel::load(dir.path(), &dev) {
        Err(ModelError::File { path, .. }) => assert!(path.ends_with(CONFIG_FILE)),
        other => panic!("expected a file error, got {other:?}"),
    }
    assert!(NtgModel::load(dir.path().join("missing"), &dev).is_err());

    // Weights of a different shape are rejected.
    let other = tempfile::tempdir().unwrap();
    model.save(other.path()).unwrap();
    let mut cfg = small_config(11);
    cfg.localizer.encoder =
        EncoderConfig::State(StateEncoderConfig::new(D).with_hidden(17).with_out_dim(12));
    cfg.edge.encoder = cfg.localizer.encoder.clone();
    std::fs::write(
        other.path().join(CONFIG_FILE),
        serde_json::to_string(&cfg).unwrap(),
    )
    .unwrap();
    // (Without its checksum, as a config edited by hand in a run saved
    // before checksums: the shapes are what is checked.)
    std::fs::remove_file(other.path().join(format!("{CONFIG_FILE}.sha256"))).unwrap();
    assert!(matches!(
        NtgModel::load(other.path(), &dev),
        Err(ModelError::File { .. })
    ));
}

#[test]
fn weights_that_diverged_to_nan_are_refused_at_load_naming_the_file() {
    let dev = device();
    let mut model = NtgModel::new(small_config(14), &dev).unwrap();
    let [n, h] = model.localizer.nodes.val().dims();
    model.localizer.nodes = burn::module::Param::from_data(
        burn::tensor::TensorData::new(vec![f32::NAN; n * h], [n, h]),
        &dev,
    );
    let dir = tempfile::tempdir().unwrap();
    model.save(dir.path()).unwrap();
    let err = NtgModel::load(dir.path(), &dev).unwrap_err().to_string();
    assert!(
        err.contains(WEIGHTS_FILE) && err.contains("1 of its weight tensors hold NaN"),
        "{err}"
    );
}

/// Found by the `checkpoint` fuzz target: burn panics on an optimizer
/// record whose tensors carry no parameter id; loading it (with no checksum
/// sidecar, as for files saved before sidecars) is an error naming the file.
#[test]
fn an_optimizer_file_that_makes_burn_panic_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("optimizer.bpk");
    std::fs::write(
        &path,
        include_bytes!("testdata/optimizer-without-param-ids.bpk"),
    )
    .unwrap();
    let fresh: burn::optim::ModuleOptimizer = burn::optim::AdamConfig::new().init();
    let Err(err) = crate::load_optimizer(fresh, &path) else {
        panic!("a malformed optimizer record loaded");
    };
    let err = err.to_string();
    assert!(
        err.contains("optimizer.bpk") && err.contains("not a valid checkpoint file"),
        "{err}"
    );
}

#[test]
fn damaged_checkpoint_files_fail_their_checksum_naming_the_file() {
    let dev = device();
    let model = NtgModel::new(small_config(13), &dev).unwrap();
    let saved = tempfile::tempdir().unwrap();
    model.save(saved.path()).unwrap();
    let weights = std::fs::read(saved.path().join(WEIGHTS_FILE)).unwrap();
    let damaged = |edit: &dyn Fn(&mut Vec<u8>)| {
        let dir = tempfile::tempdir().unwrap();
        model.save(dir.path()).unwrap();
        let mut bytes = weights.clone();
        edit(&mut bytes);
        std::fs::write(dir.path().join(WEIGHTS_FILE), bytes).unwrap();
        match NtgModel::load(dir.path(), &dev) {
            Err(e @ ModelError::File { .. }) => {
                let message = e.to_string();
                assert!(message.contains(WEIGHTS_FILE), "{message}");
                assert!(message.contains("checksum mismatch"), "{message}");
            }
            other => panic!("expected a checksum error, got {other:?}"),
        }
        dir
    };
    // 20 bytes flipped in the middle (the weights, not the header).
    damaged(&|b: &mut Vec<u8>| {
        let mid = b.len() / 2;
        for x in &mut b[mid..mid + 20] {
            *x = !*x;
        }
    });
    damaged(&|b: &mut Vec<u8>| b.truncate(b.len() / 3));
    // The optimizer state too.
    let opt = saved.path().join("optimizer.bpk");
    save_optimizer(&burn::optim::AdamConfig::new().init(), &opt).unwrap();
    std::fs::write(&opt, b"garbage").unwrap();
    let Err(err) = load_optimizer(burn::optim::AdamConfig::new().init(), &opt) else {
        panic!("a damaged optimizer state loaded");
    };
    assert!(err.to_string().contains("checksum mismatch"), "{err}");
    // A checkpoint saved before checksums (no sidecars) loads unchecked.
    std::fs::remove_file(saved.path().join(format!("{WEIGHTS_FILE}.sha256"))).unwrap();
    std::fs::remove_file(saved.path().join(format!("{CONFIG_FILE}.sha256"))).unwrap();
    assert!(NtgModel::load(saved.path(), &dev).is_ok());
}

#[test]
fn optimizer_state_round_trips() {
    use burn::optim::{AdamConfig, GradientsParams};
    let dev = device().autodiff();
    let dir = tempfile::tempdir().unwrap();
    let mut model = NtgModel::new(small_config(12), &dev).unwrap();
    let mut optim = AdamConfig::new().init();
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let obs = rows_tensor(&random_rows(&mut rng, 8, D), D, &dev).unwrap();
    let labels = ids_tensor(&ids(&[0, 2, 3, 4, 5, 6, 2, 3]), N, &dev).unwrap();
    let step = |model: NtgModel, optim: &mut burn::optim::ModuleOptimizer| {
        let logits = model.localizer.forward(obs.clone()).unwrap();
        let loss = model.localizer.loss(logits, labels.clone()).unwrap().loss;
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        optim.step(1e-2, model, grads)
    };
    model = step(model, &mut optim);
    model.save(dir.path()).unwrap();
    let opt_path = dir.path().join("optim.bpk");
    save_optimizer(&optim, &opt_path).unwrap();
    // Continue in place, and from the checkpoint: the same next step.
    let a = step(model, &mut optim);
    let mut restored_optim = load_optimizer(AdamConfig::new().init(), &opt_path).unwrap();
    let restored = NtgModel::load(dir.path(), &dev).unwrap();
    let b = step(restored, &mut restored_optim);
    let wa = to_vec(a.localizer.nodes.val()).unwrap();
    let wb = to_vec(b.localizer.nodes.val()).unwrap();
    assert!(close(&wa, &wb, 1e-6));
    assert!(load_optimizer(AdamConfig::new().init(), dir.path().join("nope.bpk")).is_err());
}

#[test]
fn config_validation_catches_inconsistency() {
    let mut c = small_config(0);
    c.edge.gcn_dim = 3;
    assert!(matches!(c.validate(), Err(ModelError::Config(_))));
    let mut c = small_config(0);
    c.gcn.num_nodes = N + 1;
    assert!(c.validate().is_err());
    let mut c = small_config(0);
    c.edge_threshold = 2.0;
    assert!(c.validate().is_err());
    assert!(small_config(0).validate().is_ok());
    assert_eq!("flex".parse::<BackendKind>().unwrap(), BackendKind::Flex);
    assert!("tpu".parse::<BackendKind>().is_err());
    assert!(BackendKind::available().contains(&BackendKind::Flex));
}

/// The two CPU backends agree on the same weights (a build with the
/// `ndarray` feature: `cargo test -p ntg-model --features ndarray`).
#[cfg(feature = "ndarray")]
#[test]
fn flex_and_ndarray_agree() {
    let flex = BackendKind::Flex.device().unwrap();
    #[allow(deprecated)] // burn-ndarray is deprecated upstream, still supported here
    let nd = Device::ndarray();
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let demo = random_rows(&mut rng, 5, D);
    let path = ids(&[2, 3, 2, 4]);
    let mut results = Vec::new();
    for dev in [flex, nd] {
        let model = NtgModel::new(small_config(13), &dev).unwrap();
        let policy = NtgPolicy::from_actions(&model, &path).unwrap();
        let batch = DemoBatch::new(&[(&demo[..], &path[..])], D, N, &dev).unwrap();
        let loss = to_vec(model.interpreter.loss(&batch).unwrap().loss).unwrap();
        let mut v = to_vec(
            model
                .gcn
                .forward(adjacency_tensor(&[policy.initial_graph()], N, &dev).unwrap())
                .unwrap()
                .adjacency,
        )
        .unwrap();
        v.extend(loss);
        v.extend(
            policy
                .log_probabilities(&demo[0])
                .unwrap()
                .into_iter()
                .map(|l| l.max(-1e6)),
        );
        results.push(v);
    }
    assert!(close(&results[0], &results[1], 1e-4));
}

#[test]
fn model_and_policy_can_go_to_other_threads() {
    fn send<T: Send>() {}
    fn sync<T: Sync>() {}
    send::<NtgModel>();
    sync::<NtgModel>();
    send::<NtgPolicy>();
    // A policy built on one thread runs on another.
    let model = NtgModel::new(small_config(14), &device()).unwrap();
    let policy = NtgPolicy::from_actions(&model, &ids(&[2, 3])).unwrap();
    let handle = std::thread::spawn(move || policy.action_distribution(&one_hot_row(0)).is_ok());
    assert!(handle.join().unwrap());
}

/// With the content score switched off (`W_a = 0`) and the location
/// weights on "one frame further", the attention steps through the demo
/// one frame per token, starting at frame 1, whatever the demo's length.
#[test]
fn location_attention_steps_one_frame_per_token() {
    let dev = device();
    let mut config = small_config(4).interpreter;
    config.bidirectional = Some(true);
    config.input_feeding = Some(true);
    config.location_attention = Some(true);
    let mut interp = config.init(4, &dev).unwrap();
    let h = interp.attn.weight.dims()[0];
    interp.attn.weight = Param::from_data(TensorData::new(vec![0.0f32; h * h], [h, h]), &dev);
    let w = [0.0f32, 0.0, 1.0, 0.0]; // shifts -1, 0, +1, +2
    interp.location = Some(Param::from_data(TensorData::new(w.to_vec(), [4]), &dev));
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for frames in [4usize, 9] {
        let obs = random_rows(&mut rng, frames, D);
        let actions: Vec<ActionId> = (0..frames - 1).map(|i| ActionId::new(2 + i % 5)).collect();
        let batch = DemoBatch::new(&[(&obs[..], &actions[..])], D, N, &dev).unwrap();
        let att = to_vec(interp.attention(&batch).unwrap()).unwrap();
        for (t, row) in att.chunks(frames).enumerate().take(frames - 1) {
            let best = (0..frames)
                .max_by(|&a, &b| row[a].total_cmp(&row[b]))
                .unwrap();
            assert_eq!(best, t + 1, "token {t} of a {frames}-frame demo: {row:?}");
        }
    }
    // Without input feeding the option is refused.
    let mut bad = small_config(4).interpreter;
    bad.location_attention = Some(true);
    assert!(matches!(bad.init(0, &dev), Err(ModelError::Config(_))));
}

/// Frames that show the last action (one-hot over the `N` nodes, `<start>`
/// first) and random actions: frame `k + 1` reveals action `k`.
fn revealing_demo(rng: &mut ChaCha8Rng, len: usize) -> (Vec<Vec<f32>>, Vec<ActionId>) {
    let actions: Vec<ActionId> = (0..len)
        .map(|_| ActionId::new(rng.random_range(2..N)))
        .collect();
    let frame = |id: usize| {
        let mut row = vec![0.0f32; D];
        row[id] = 1.0;
        row
    };
    let mut frames = vec![frame(Vocabulary::START.index())];
    frames.extend(actions.iter().map(|a| frame(a.index())));
    (frames, actions)
}

/// The length-independent interpreter (local annotations, input feeding,
/// location-aware attention, stateless decoder), trained on demos of 1 to
/// 5 actions only, transcribes demos of 9 actions.
#[test]
fn stepping_interpreter_learns_and_carries_over_to_longer_demos() {
    use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
    let dev = device().autodiff();
    let mut config = small_config(8).interpreter;
    config.input_feeding = Some(true);
    config.location_attention = Some(true);
    config.stateless_decoder = Some(true);
    config.local_annotations = Some(true);
    let mut interp = config.init(8, &dev).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let long: Vec<_> = (0..20).map(|_| revealing_demo(&mut rng, 9)).collect();
    let exact = |model: &DemoInterpreter| {
        long.iter()
            .filter(|(frames, actions)| model.decode(frames).unwrap() == *actions)
            .count()
    };
    let before = exact(&interp.valid());
    let mut optimizer: ModuleOptimizer = AdamConfig::new().init();
    for _ in 0..300 {
        let demos: Vec<_> = (0..16)
            .map(|_| {
                let len = rng.random_range(1..=5);
                revealing_demo(&mut rng, len)
            })
            .collect();
        let pairs: Vec<(&[Vec<f32>], &[ActionId])> =
            demos.iter().map(|(f, a)| (&f[..], &a[..])).collect();
        let batch = DemoBatch::new(&pairs, D, N, &dev).unwrap();
        let loss = interp.loss(&batch).unwrap();
        let grads = GradientsParams::from_grads(loss.loss.backward(), &interp);
        interp = optimizer.step(3e-3, interp, grads);
    }
    let after = exact(&interp.valid());
    eprintln!("exact transcriptions of 9-action demos: {before}/20 -> {after}/20");
    assert!(before < 2, "untrained: {before}/20");
    assert!(
        after >= 18,
        "only {after}/20 demos of 9 actions transcribed exactly"
    );
}

#[test]
fn pending_nodes_are_the_graph_actions_not_yet_executed() {
    let path = ids(&[2, 3, 2, 4]);
    let graph = Ctg::from_path(N, &path).unwrap();
    // <start> and <end> have edges but are never pending; 5 and 6 are not
    // in the graph.
    assert_eq!(
        pending_nodes(&graph, &[]),
        vec![0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0]
    );
    assert_eq!(
        pending_nodes(&graph, &ids(&[2, 6, 2])),
        vec![0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0]
    );
    assert!(pending_nodes(&graph, &path).iter().all(|&p| p == 0.0));
    assert_eq!(
        executed_actions(N, &ids(&[3, 3, 1])),
        vec![0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    );
}

#[test]
fn the_edge_classifier_reads_its_memory_and_refuses_a_missing_one() {
    let dev = device();
    let vocab = Vocabulary::new(["a", "b", "c", "d", "e"]).unwrap();
    let mut config = small_config(3);
    config.edge.memory_dim = Some(N);
    let model = NtgModel::new(config, &dev).unwrap();
    let plain = NtgModel::new(small_config(3), &dev).unwrap();
    let b = 2;
    let obs = rows_tensor(&[one_hot_row(0), one_hot_row(1)], D, &dev).unwrap();
    let nodes = ids_tensor(&ids(&[0, 2]), N, &dev).unwrap();
    let ne_gcn = model.gcn.initial_embeddings(b);
    let all = Tensor::<2, Bool>::from_data(TensorData::new(vec![true; b * N], [b, N]), &dev);
    let forward = |m: &NtgModel, memory: Option<Vec<Vec<f32>>>| {
        m.edges.forward(
            obs.clone(),
            nodes.clone(),
            ne_gcn.clone(),
            m.localizer.node_embeddings(),
            all.clone(),
            memory.map(|rows| rows_tensor(&rows, rows[0].len(), &dev).unwrap()),
        )
    };
    let none = vec![vec![0.0; N]; b];
    let some = vec![vec![1.0; N]; b];
    let a = to_vec(forward(&model, Some(none.clone())).unwrap()).unwrap();
    let c = to_vec(forward(&model, Some(some)).unwrap()).unwrap();
    assert!(!close(&a, &c, 1e-4), "the memory changes the logits");
    assert!(forward(&model, None).is_err());
    assert!(forward(&model, Some(vec![vec![0.0; 3]; b])).is_err());
    assert!(forward(&plain, Some(none)).is_err());
    assert!(forward(&plain, None).is_ok());

    // The policy asks for the executed actions before scoring, and they
    // change its distribution.
    let demo: Vec<Vec<f32>> = (0..4).map(one_hot_row).collect();
    let policy = NtgPolicy::from_demo(&model, &demo, &vocab).unwrap();
    assert!(policy.has_memory());
    let o = one_hot_row(2);
    assert!(policy.action_distribution(&o).is_err());
    policy.set_executed(&[]);
    let fresh = policy.edge_probabilities_for(policy.graph(), &o).unwrap();
    policy.set_executed(policy.demo_actions());
    let done = policy.edge_probabilities_for(policy.graph(), &o).unwrap();
    assert!(!close(&fresh, &done, 1e-6));
    // Saved and loaded, the memory size survives.
    let dir = tempfile::tempdir().unwrap();
    model.save(dir.path()).unwrap();
    let loaded = NtgModel::load(dir.path(), &dev).unwrap();
    assert_eq!(loaded.edges.memory_dim, N);
    assert!(
        !NtgPolicy::from_demo(&plain, &demo, &vocab)
            .unwrap()
            .has_memory()
    );
}

/// The paper's linear `W` makes an edge logit a sum of an observation term
/// and a node term, so it cannot learn a rule where the right edge depends
/// on the observation *and* the node together (here an XOR of one
/// observation bit and which of two nodes the agent is at); with the
/// fusion layer the same classifier learns it exactly.
#[test]
fn only_the_fusion_layer_learns_a_node_dependent_observation_rule() {
    use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
    let dev = device().autodiff();
    // Rows: (observation bit, node 2 or 3) -> action 4 if bit xor (node
    // is 3), else action 5; both are successors everywhere.
    let cases: Vec<(usize, usize, usize)> = (0..2)
        .flat_map(|bit| {
            (2..4).map(move |node| (bit, node, if (bit == 1) != (node == 3) { 4 } else { 5 }))
        })
        .collect();
    let b = cases.len();
    let rows: Vec<Vec<f32>> = cases.iter().map(|&(bit, _, _)| one_hot_row(bit)).collect();
    let nodes: Vec<ActionId> = cases.iter().map(|&(_, n, _)| ActionId::new(n)).collect();
    let targets: Vec<ActionId> = cases.iter().map(|&(_, _, a)| ActionId::new(a)).collect();
    let mut mask = vec![false; b * N];
    for row in mask.chunks_mut(N) {
        row[4] = true;
        row[5] = true;
    }
    let accuracy_after_training = |fusion: Option<usize>| -> f32 {
        let mut config = small_config(11);
        config.edge.fusion_hidden = fusion;
        let mut model = NtgModel::new(config, &dev).unwrap();
        let mut optimizer: ModuleOptimizer = AdamConfig::new().init();
        let mut accuracy = 0.0;
        for _ in 0..400 {
            let logits = model
                .edges
                .forward(
                    rows_tensor(&rows, D, &dev).unwrap(),
                    ids_tensor(&nodes, N, &dev).unwrap(),
                    model.gcn.initial_embeddings(b),
                    model.localizer.node_embeddings(),
                    Tensor::<2, Bool>::from_data(TensorData::new(mask.clone(), [b, N]), &dev),
                    None,
                )
                .unwrap();
            let out = model
                .edges
                .loss(logits, ids_tensor(&targets, N, &dev).unwrap())
                .unwrap();
            accuracy = out.accuracy;
            let grads = GradientsParams::from_grads(out.loss.backward(), &model);
            model = optimizer.step(1e-2, model, grads);
        }
        accuracy
    };
    let linear = accuracy_after_training(None);
    let fused = accuracy_after_training(Some(16));
    eprintln!("XOR rule accuracy: linear W {linear}, fusion layer {fused}");
    assert!(linear <= 0.75 + 1e-6, "linear W fit an XOR: {linear}");
    assert_eq!(fused, 1.0, "the fusion layer did not learn the rule");
}

/// Soft edges: each row of ε is the hard policy's softmax over every
/// allowed successor, reweighted by the completed graph's edge
/// probabilities (demo edges at 1, floored), and π still sums to 1.
#[test]
fn soft_edges_weigh_the_edge_classifier_by_the_gcn_probabilities() {
    let dev = device();
    let hard_model = NtgModel::new(small_config(3), &dev).unwrap();
    let mut soft_model = hard_model.clone();
    soft_model.config.soft_edges = Some(true);
    let path = ids(&[2, 3, 2, 4]);
    let hard = NtgPolicy::from_actions(&hard_model, &path).unwrap();
    let soft = NtgPolicy::from_actions(&soft_model, &path).unwrap();
    assert!(hard.edge_weights().is_none());
    assert_eq!(hard.execution_graph(), hard.graph());
    // Same GCN: same probabilities and thresholded graph.
    assert_eq!(soft.edge_probabilities(), hard.edge_probabilities());
    assert_eq!(soft.graph(), hard.graph());
    let weights = soft.edge_weights().unwrap();
    assert!(
        weights.adjacency().iter().any(|&w| w > 0.01 && w < 0.99),
        "the untrained GCN should give some edge a probability strictly between 0 and 1"
    );
    let full = Ctg::fully_connected(N);
    assert_eq!(soft.execution_graph(), &full);
    let initial = Ctg::from_path(N, &path).unwrap();
    for from in 0..N {
        for to in 0..N {
            let (f, t) = (ActionId::new(from), ActionId::new(to));
            let w = weights.weight(f, t);
            if !full.has_edge(f, t) {
                assert_eq!(w, 0.0);
            } else if initial.has_edge(f, t) {
                assert_eq!(w, 1.0);
            } else {
                let p = soft.edge_probabilities().weight(f, t);
                assert_eq!(w, p.clamp(SOFT_EDGE_FLOOR, 1.0));
            }
        }
    }
    let obs = one_hot_row(3);
    let p_hard = hard.edge_probabilities_for(&full, &obs).unwrap();
    let p_soft = soft.edge_probabilities_for(&full, &obs).unwrap();
    for from in 0..N {
        let f = ActionId::new(from);
        let row = &p_hard[from * N..(from + 1) * N];
        let z: f32 = (0..N)
            .map(|to| weights.weight(f, ActionId::new(to)) * row[to])
            .sum();
        for to in 0..N {
            let expected = if z > 0.0 {
                weights.weight(f, ActionId::new(to)) * row[to] / z
            } else {
                0.0
            };
            let got = p_soft[from * N + to];
            assert!(
                (got - expected).abs() < 1e-4,
                "{from} -> {to}: {got} vs {expected}"
            );
        }
    }
    let logp = soft.log_probabilities(&obs).unwrap();
    let total: f32 = logp.iter().map(|l| l.exp()).sum();
    assert!((total - 1.0).abs() < 1e-4, "{total}");
    let dist = soft.action_distribution(&obs).unwrap();
    for (a, &l) in logp.iter().enumerate() {
        let p = dist.probability(ActionId::new(a));
        assert!((l.exp() - p).abs() < 1e-4, "action {a}: {} vs {p}", l.exp());
    }
}

/// Checkpoints written before the optional settings existed (no
/// `soft_edges`, `fusion_hidden` or `memory_dim` in `config.json`) still
/// load, with the options off.
#[test]
fn checkpoints_without_the_optional_settings_still_load() {
    let dev = device();
    let model = NtgModel::new(small_config(5), &dev).unwrap();
    let dir = tempfile::tempdir().unwrap();
    model.save(dir.path()).unwrap();
    let path = dir.path().join("config.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let root = json.as_object_mut().unwrap();
    assert!(root.remove("soft_edges").is_some());
    let edge = root["edge"].as_object_mut().unwrap();
    assert!(edge.remove("fusion_hidden").is_some());
    assert!(edge.remove("memory_dim").is_some());
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    // Nor had they checksums.
    std::fs::remove_file(dir.path().join("config.json.sha256")).unwrap();
    let loaded = NtgModel::load(dir.path(), &dev).unwrap();
    assert!(!loaded.config.uses_soft_edges());
    assert_eq!(loaded.edges.memory_dim, 0);
    assert!(loaded.edges.fusion.is_none());
}

/// The weighted edge loss is a weighted mean over rows: a row with weight
/// 0 does not count, equal weights give the plain loss, and the accuracy
/// stays unweighted.
#[test]
fn weighted_edge_loss_is_a_weighted_mean_over_rows() {
    let dev = device();
    let model = NtgModel::new(small_config(4), &dev).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let b = 6;
    let obs = rows_tensor(&random_rows(&mut rng, b, D), D, &dev).unwrap();
    let nodes = ids_tensor(&ids(&[2, 3, 4, 2, 3, 4]), N, &dev).unwrap();
    let all = Tensor::<2, Bool>::from_data(TensorData::new(vec![true; b * N], [b, N]), &dev);
    let logits = model
        .edges
        .forward(
            obs,
            nodes,
            model.gcn.initial_embeddings(b),
            model.localizer.node_embeddings(),
            all,
            None,
        )
        .unwrap();
    let next = ids_tensor(&ids(&[3, 4, 5, 6, 2, 3]), N, &dev).unwrap();
    let weights = |w: Vec<f32>| {
        let n = w.len();
        Tensor::<1>::from_data(TensorData::new(w, [n]), &dev)
    };
    let loss = |w: Vec<f32>, rows: std::ops::Range<usize>| {
        let l = logits.clone().slice([rows.clone(), 0..N]);
        let t = next.clone().narrow(0, rows.start, rows.len());
        let n = l.dims()[0];
        model.edges.weighted_loss(l, t, weights(w[..n].to_vec()))
    };
    let plain = model.edges.loss(logits.clone(), next.clone()).unwrap();
    let same = loss(vec![2.0; b], 0..b).unwrap();
    assert!(close(
        &to_vec(plain.loss).unwrap(),
        &to_vec(same.loss).unwrap(),
        1e-5
    ));
    let masked = loss(vec![1.0, 1.0, 1.0, 0.0, 0.0, 0.0], 0..b).unwrap();
    let first_half = model
        .edges
        .loss(
            logits.clone().slice([0..3, 0..N]),
            next.clone().narrow(0, 0, 3),
        )
        .unwrap();
    assert!(close(
        &to_vec(masked.loss).unwrap(),
        &to_vec(first_half.loss).unwrap(),
        1e-5
    ));
    assert_eq!(masked.accuracy, plain.accuracy, "accuracy is unweighted");
    assert!(
        model
            .edges
            .weighted_loss(logits, next, weights(vec![1.0; 3]))
            .is_err()
    );
}

/// The location step prior sets only the initial weight of shift +1, and
/// leaves every other weight as it was.
#[test]
fn location_step_prior_sets_the_initial_shift_plus_one_weight() {
    let dev = device();
    let base = small_config(2)
        .interpreter
        .with_input_feeding(Some(true))
        .with_location_attention(Some(true));
    let plain = base.clone().init(5, &dev).unwrap();
    let primed = base
        .with_location_step_prior(Some(0.3))
        .init(5, &dev)
        .unwrap();
    use crate::interpreter::LOCATION_SHIFTS;
    let location = |i: &DemoInterpreter| to_vec(i.location.as_ref().unwrap().val()).unwrap();
    assert_eq!(location(&plain), vec![0.0; LOCATION_SHIFTS.len()]);
    let expected: Vec<f32> = LOCATION_SHIFTS
        .iter()
        .map(|&j| if j == 1 { 0.3 } else { 0.0 })
        .collect();
    assert_eq!(location(&primed), expected);
    let others = |i: &DemoInterpreter| {
        [
            i.out.weight.val(),
            i.attn.weight.val(),
            i.combine.weight.val(),
        ]
        .map(|t| to_vec(t).unwrap())
    };
    assert_eq!(others(&plain), others(&primed));
}

/// A wider location window has a weight per shift −1..=k and starts every
/// forward shift at the prior (the default window primes +1 only); a
/// window outside 2..=MAX_LOCATION_SHIFT is refused; the wide interpreter
/// trains and decodes like the default one.
#[test]
fn a_wide_location_window_primes_every_forward_shift() {
    use crate::interpreter::{MAX_LOCATION_SHIFT, location_shifts};
    let dev = device();
    let base = small_config(2)
        .interpreter
        .with_input_feeding(Some(true))
        .with_location_attention(Some(true))
        .with_location_step_prior(Some(0.3));
    let wide = base
        .clone()
        .with_location_max_shift(Some(10))
        .init(5, &dev)
        .unwrap();
    let weights = to_vec(wide.location.as_ref().unwrap().val()).unwrap();
    let shifts = location_shifts(Some(10));
    assert_eq!(shifts, (-1..=10).collect::<Vec<isize>>());
    let expected: Vec<f32> = shifts
        .iter()
        .map(|&j| if j >= 1 { 0.3 } else { 0.0 })
        .collect();
    assert_eq!(weights, expected);
    for bad in [0, 1, MAX_LOCATION_SHIFT + 1] {
        assert!(
            base.clone()
                .with_location_max_shift(Some(bad))
                .init(5, &dev)
                .is_err(),
            "max shift {bad} accepted"
        );
    }
    // Ten frames of a demo of three actions: teacher-forced attention rows
    // sum to one, and greedy decoding stops within the limit.
    let rows = random_rows(&mut ChaCha8Rng::seed_from_u64(3), 10, D);
    let actions = [ActionId::new(2), ActionId::new(3), ActionId::new(2)];
    let batch = DemoBatch::new(&[(&rows[..], &actions[..])], D, wide.num_nodes, &dev).unwrap();
    let attention = wide.attention(&batch).unwrap();
    let [_, len, steps] = attention.dims();
    assert_eq!((len, steps), (4, 10));
    for total in to_vec(attention.sum_dim(2)).unwrap() {
        assert!((total - 1.0).abs() < 1e-5, "attention row sums to {total}");
    }
    assert!(wide.decode(&rows).unwrap().len() <= wide.max_decode_len);
}

/// Every float parameter's gradient, in the module's order.
struct ParamGrads<'a> {
    grads: &'a burn::tensor::Gradients,
    out: Vec<TensorData>,
}

impl burn::module::ModuleVisitor for ParamGrads<'_> {
    fn visit_float<const DIM: usize>(&mut self, param: &burn::module::Param<Tensor<DIM>>) {
        if let Some(g) = param.val().grad(self.grads) {
            self.out.push(g.into_data());
        }
    }
}

/// Runs `f` with GRU sequences fused (`false`) or as composed steps.
fn with_composed_gru<T>(composed: bool, f: impl FnOnce() -> T) -> T {
    crate::nn::COMPOSED_GRU_ONLY.with(|c| c.set(composed));
    let out = f();
    crate::nn::COMPOSED_GRU_ONLY.with(|c| c.set(false));
    out
}

/// The interpreter's loss and every parameter's gradient are bit-identical
/// with the fused GRU sequence and with composed steps, in every
/// configuration the experiments use (encoder states read by attention,
/// the decoder started from the encoder's final state, a backward encoder,
/// input feeding, local annotations, pooled frames), on a batch of demos
/// of different lengths (masked).
#[test]
fn interpreter_gradients_are_the_same_with_the_fused_gru_sequence() {
    use burn::module::Module;
    let dev = device().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let (batch, _, _) = demo_batch(&dev, &mut rng);
    type Variant = (&'static str, fn(&mut DemoInterpreterConfig));
    let variants: [Variant; 6] = [
        ("defaults", |_| {}),
        ("unidirectional", |c| c.bidirectional = Some(false)),
        ("bidirectional", |c| c.bidirectional = Some(true)),
        ("input feeding", |c| {
            c.bidirectional = Some(true);
            c.input_feeding = Some(true);
        }),
        ("object collection's", |c| {
            c.input_feeding = Some(true);
            c.location_attention = Some(true);
            c.stateless_decoder = Some(true);
            c.local_annotations = Some(true);
        }),
        ("frames pooled", |c| c.frame_pool = Some(2)),
    ];
    for (what, change) in variants {
        let mut config = small_config(5).interpreter;
        change(&mut config);
        let interp = config.init(8, &dev).unwrap();
        let run = |composed: bool| {
            with_composed_gru(composed, || {
                let loss = interp.loss(&batch).unwrap().loss;
                let grads = loss.clone().backward();
                let mut visitor = ParamGrads {
                    grads: &grads,
                    out: Vec::new(),
                };
                interp.visit(&mut visitor);
                (loss.into_data(), visitor.out)
            })
        };
        let (fused, composed) = (run(false), run(true));
        assert_eq!(fused.0, composed.0, "loss ({what})");
        assert_eq!(fused.1.len(), composed.1.len(), "{what}");
        assert!(!fused.1.is_empty());
        let differing: Vec<String> = fused
            .1
            .iter()
            .zip(&composed.1)
            .enumerate()
            .filter(|(_, (f, c))| f != c)
            .map(|(i, (f, _))| format!("{i} {:?}", f.shape()))
            .collect();
        assert!(
            differing.is_empty(),
            "gradients of parameters {differing:?} differ ({what})"
        );
    }
}
