/// The small NTG model whose checkpoint files the `checkpoint` fuzz target
/// reads, shared with the `fuzz_seeds` example that writes its seeds (both
/// `include!` this file).
fn small_config() -> ntg_model::NtgConfig {
    let encoder = ntg_model::EncoderConfig::State(
        ntg_model::StateEncoderConfig::new(9)
            .with_hidden(16)
            .with_out_dim(12),
    );
    let mut config = ntg_model::NtgConfig::for_domain(7, encoder);
    config.interpreter.hidden = 16;
    config.interpreter.token_embed = 8;
    config.gcn.hidden = 10;
    config.gcn.mlp_hidden = 8;
    config.edge.gcn_dim = 10;
    config
}
