//! Several sessions' frames in one encoder and one head call ([`push_batch`]).

use super::*;

/// One session's frame in a [`push_batch`] call.
#[derive(Debug)]
pub struct BatchItem<'a> {
    /// The session's predictor.
    pub predictor: &'a mut Predictor,
    /// `O_t`, `[2, S, S]`.
    pub input: &'a [f32],
    /// Valid pixels, `[S, S]`, or `None` for all.
    pub mask: Option<&'a [bool]>,
}

/// [`Predictor::push`] for several sessions at once: one encoder call on all new frames
/// and one head call on all sessions' rows, for predictors that share one model. Results
/// are equal to pushing each item alone. An item with bad input gets its error and is left
/// out; a failed network call fails every remaining item (states unchanged).
pub fn push_batch(items: &mut [BatchItem<'_>]) -> Vec<Result<Prediction, ModelError>> {
    let mut results: Vec<Option<Result<Prediction, ModelError>>> =
        (0..items.len()).map(|_| None).collect();
    let Some(model) = items.first().map(|i| i.predictor.model.clone()) else {
        return Vec::new();
    };
    let dims = model.dims();
    let mut prepared = Vec::new();
    let (mut features, mut z, mut inputs) = (Vec::new(), Vec::new(), Vec::new());
    let mut rows = 0;
    for (k, item) in items.iter_mut().enumerate() {
        if !Arc::ptr_eq(&item.predictor.model, &model) {
            results[k] = Some(Err(ModelError::InvalidParams {
                field: "predictor",
                reason: "every predictor of a batch must use the same model".into(),
            }));
            continue;
        }
        match item.predictor.prepare(item.input, item.mask) {
            Ok(p) => {
                features.extend_from_slice(&item.predictor.feature_batch);
                z.extend_from_slice(&item.predictor.z_batch);
                inputs.extend_from_slice(item.input);
                rows += p.rows;
                prepared.push((k, p));
            }
            Err(e) => results[k] = Some(Err(e)),
        }
    }
    let run = || -> Result<(Vec<f32>, crate::network::EncoderOutput), ModelError> {
        let mut predictions = Vec::new();
        if rows > 0 && model.native_head().is_none() {
            model.predict_into(&features, &z, rows, &mut predictions)?;
        }
        let enc = model.encode(&inputs, prepared.len())?;
        Ok((predictions, enc))
    };
    if prepared.is_empty() {
        return results
            .into_iter()
            .map(|r| {
                r.unwrap_or(Err(ModelError::InvalidParams {
                    field: "batch",
                    reason: "no result".into(),
                }))
            })
            .collect();
    }
    match run() {
        Ok((predictions, enc)) => {
            let (fl, fe, l) = (dims.flow_len(), dims.features_len(), dims.latent);
            let mut row0 = 0;
            for (j, (k, p)) in prepared.into_iter().enumerate() {
                let item = &mut items[k];
                let predictor = &mut *item.predictor;
                let rows_k = p.rows;
                let (features, mu, log_sigma) = (
                    enc.features[j * fe..(j + 1) * fe].to_vec(),
                    enc.prior_mu[j * l..(j + 1) * l].to_vec(),
                    enc.prior_log_sigma[j * l..(j + 1) * l].to_vec(),
                );
                let out = if let Some(head) = model.native_head() {
                    predictor.finish_native(head, p, item.input, item.mask, features, mu, log_sigma)
                } else {
                    let pred = &predictions[row0 * fl..(row0 + rows_k) * fl];
                    row0 += rows_k;
                    let best = predictor.best_of(&p, pred, item.input, item.mask);
                    predictor.finish(p, item.input, item.mask, best, features, mu, log_sigma)
                };
                results[k] = Some(Ok(out));
            }
        }
        Err(e) => {
            let msg = e.to_string();
            for (k, _) in prepared {
                results[k] = Some(Err(ModelError::Ort {
                    context: "batched inference",
                    reason: msg.clone(),
                }));
            }
        }
    }
    results
        .into_iter()
        .map(|r| {
            r.unwrap_or(Err(ModelError::InvalidParams {
                field: "batch",
                reason: "no result".into(),
            }))
        })
        .collect()
}
