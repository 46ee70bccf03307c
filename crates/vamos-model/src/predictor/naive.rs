//! The reference `e_o`: one head call per past offset, without the encoder cache or the
//! native head ([`naive_score`]); the tests hold the predictor to it.

use super::*;

/// The straightforward computation, for reference and benchmarks: for each offset the
/// encoder runs again on the past frame and the head on that offset's `M` samples.
///
/// `past` holds `(n, O_{t-n})` in ascending `n`; draws from `rng` in the same order as
/// [`Predictor::push`], so with the same stream both give the same `e_o`. Returns `None`
/// when `past` is empty or no pixel is valid.
pub fn naive_score(
    model: &FlowModel,
    past: &[(usize, &[f32])],
    current: &[f32],
    mask: Option<&[bool]>,
    samples: usize,
    rng: &mut NormalRng,
) -> Result<Option<FlowScore>, ModelError> {
    let dims = model.dims();
    let valid_px = check_input(dims, current, mask)?;
    if past.is_empty() || valid_px == 0 || samples == 0 {
        return Ok(None);
    }
    let mut best: Option<(f64, usize, usize, Vec<f32>)> = None;
    for &(n, flow) in past {
        check_input(dims, flow, None)?;
        let enc = model.encode(flow, 1)?;
        let mut features = Vec::with_capacity(samples * enc.features.len());
        for _ in 0..samples {
            features.extend_from_slice(&enc.features);
        }
        let mut z = Vec::with_capacity(samples * dims.latent);
        draw(rng, &enc.prior_mu, &enc.prior_log_sigma, samples, &mut z);
        let pred = model.predict(&features, &z, samples)?;
        let (row, mse) = best_row(dims, &pred, samples, current, mask, valid_px);
        if best.as_ref().is_none_or(|b| mse < b.0) {
            let fl = dims.flow_len();
            best = Some((mse, n, row, pred[row * fl..(row + 1) * fl].to_vec()));
        }
    }
    Ok(best.map(|(e_o, n, sample, pred)| FlowScore {
        frame: 0,
        e_o,
        n,
        sample,
        error_map: error_map(dims, &pred, current, mask),
        valid_px,
    }))
}
