//! Loading a graph and checking it against the contract: the ONNX opset, the inputs' and
//! outputs' names, types and shapes, and the ONNX Runtime session it runs in.

use super::*;

pub(super) fn ort_err<E: std::fmt::Display>(context: &'static str) -> impl FnOnce(E) -> ModelError {
    move |e| ModelError::Ort {
        context,
        reason: e.to_string(),
    }
}

/// A tensor outlet's element type and shape (-1 = dynamic).
pub(super) fn tensor_shape(dtype: &ValueType) -> Option<(TensorElementType, Vec<i64>)> {
    match dtype {
        ValueType::Tensor { ty, shape, .. } => Some((*ty, shape.to_vec())),
        _ => None,
    }
}

/// Checks a graph's inputs or outputs: exactly `expected` names, float32, rank, dynamic
/// first axis, and the given fixed dims (`None` = any fixed positive size). Returns the
/// shapes in the order of `expected`.
pub(super) fn check_outlets(
    member: &str,
    kind: &str,
    outlets: &[ort::value::Outlet],
    expected: &[(&str, &[Option<i64>])],
) -> Result<Vec<Vec<i64>>, ModelError> {
    let sig = |reason: String| ModelError::Signature {
        member: member.into(),
        reason,
    };
    let mut names: Vec<&str> = outlets.iter().map(|o| o.name()).collect();
    names.sort_unstable();
    let mut want: Vec<&str> = expected.iter().map(|(n, _)| *n).collect();
    want.sort_unstable();
    if names != want {
        return Err(sig(format!("{kind} are {names:?}, expected {want:?}")));
    }
    let mut shapes = Vec::new();
    for (name, dims) in expected {
        let outlet = outlets
            .iter()
            .find(|o| o.name() == *name)
            .ok_or_else(|| sig(format!("no {kind} {name}")))?;
        let (ty, shape) = tensor_shape(outlet.dtype())
            .ok_or_else(|| sig(format!("{kind} {name} is not a tensor")))?;
        if ty != TensorElementType::Float32 {
            return Err(sig(format!("{kind} {name} is {ty:?}, expected float32")));
        }
        if shape.len() != dims.len() + 1 {
            return Err(sig(format!(
                "{kind} {name} has shape {shape:?}, expected rank {} ([N, ...])",
                dims.len() + 1
            )));
        }
        if shape[0] >= 0 {
            return Err(sig(format!(
                "{kind} {name} has a fixed batch axis ({}); the contract makes N dynamic",
                shape[0]
            )));
        }
        for (i, want) in dims.iter().enumerate() {
            let got = shape[i + 1];
            let ok = match want {
                Some(w) => got == *w,
                None => got > 0,
            };
            if !ok {
                return Err(sig(format!(
                    "{kind} {name} has shape {shape:?}, expected [N{}]",
                    dims.iter()
                        .map(|d| d.map_or(", fixed".to_string(), |v| format!(", {v}")))
                        .collect::<String>()
                )));
            }
        }
        shapes.push(shape);
    }
    Ok(shapes)
}

pub(super) fn check_opset(
    member: &str,
    bytes: &[u8],
    manifest_opset: u64,
) -> Result<(), ModelError> {
    let header = onnx_proto::read_header(bytes).map_err(|reason| ModelError::InvalidOnnx {
        member: member.into(),
        reason,
    })?;
    let found = header
        .default_opset()
        .ok_or_else(|| ModelError::InvalidOnnx {
            member: member.into(),
            reason: "no opset import for the default ONNX domain".into(),
        })?;
    if found != manifest_opset {
        return Err(ModelError::Opset {
            member: member.into(),
            found,
            reason: format!("the manifest says {manifest_opset}"),
        });
    }
    if !SUPPORTED_OPSETS.contains(&found) {
        return Err(ModelError::Opset {
            member: member.into(),
            found,
            reason: format!(
                "supported: {}..={}",
                SUPPORTED_OPSETS.start(),
                SUPPORTED_OPSETS.end()
            ),
        });
    }
    Ok(())
}

pub(super) fn session(
    member: &str,
    bytes: &[u8],
    options: &LoadOptions,
) -> Result<Session, ModelError> {
    let rt = runtime::ensure(options.runtime)?;
    let builder = Session::builder(&rt.environment)
        .map_err(ort_err("creating a session builder"))?
        .with_optimization_level(GraphOptimizationLevel::All)
        .map_err(ort_err("setting the optimisation level"))?
        .with_intra_threads(options.intra_threads)
        .map_err(ort_err("setting intra-op threads"))?;
    let mut builder = builder;
    builder
        .commit_from_memory(bytes)
        .map_err(|e| ModelError::InvalidOnnx {
            member: member.into(),
            reason: e.to_string(),
        })
}
