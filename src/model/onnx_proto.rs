//! A minimal reader of the ONNX `ModelProto` header: the opset imports and IR version.
//!
//! ONNX Runtime does not report a model's opset; reading the two top-level protobuf fields
//! needed here takes a few lines and no protobuf dependency. The walk also rejects a
//! truncated or garbled file early with a clear message.

/// What the model header says.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct OnnxHeader {
    /// `ModelProto.ir_version` (field 1).
    pub ir_version: u64,
    /// `ModelProto.opset_import` (field 8): (domain, version); "" is the default domain.
    pub opsets: Vec<(String, u64)>,
    /// Whether a graph (field 7) is present.
    pub has_graph: bool,
}

impl OnnxHeader {
    /// The default domain's opset ("" or "ai.onnx").
    pub fn default_opset(&self) -> Option<u64> {
        self.opsets
            .iter()
            .find(|(d, _)| d.is_empty() || d == "ai.onnx")
            .map(|(_, v)| *v)
    }
}

fn varint(buf: &[u8], pos: &mut usize) -> Result<u64, String> {
    let mut value = 0u64;
    for shift in (0..64).step_by(7) {
        let b = *buf
            .get(*pos)
            .ok_or_else(|| format!("truncated varint at byte {pos}"))?;
        *pos += 1;
        value |= u64::from(b & 0x7f) << shift;
        if b & 0x80 == 0 {
            return Ok(value);
        }
    }
    Err(format!("varint longer than 10 bytes before byte {pos}"))
}

/// Walks the fields of one message: `on_bytes(field, payload)` for length-delimited
/// fields, `on_varint(field, value)` for varints; fixed-width fields are skipped.
fn walk(
    buf: &[u8],
    mut on_bytes: impl FnMut(u64, &[u8]) -> Result<(), String>,
    mut on_varint: impl FnMut(u64, u64),
) -> Result<(), String> {
    let mut pos = 0;
    while pos < buf.len() {
        let key = varint(buf, &mut pos)?;
        let (field, wire) = (key >> 3, key & 7);
        if field == 0 {
            return Err(format!("field number 0 at byte {pos}"));
        }
        match wire {
            0 => {
                let v = varint(buf, &mut pos)?;
                on_varint(field, v);
            }
            1 | 5 => {
                let n = if wire == 1 { 8 } else { 4 };
                if pos + n > buf.len() {
                    return Err(format!("truncated fixed-width field {field}"));
                }
                pos += n;
            }
            2 => {
                let len = usize::try_from(varint(buf, &mut pos)?)
                    .map_err(|_| "length overflows".to_string())?;
                let end = pos
                    .checked_add(len)
                    .filter(|&e| e <= buf.len())
                    .ok_or_else(|| {
                        format!(
                            "field {field} claims {len} bytes at byte {pos}, file has {}",
                            buf.len()
                        )
                    })?;
                on_bytes(field, &buf[pos..end])?;
                pos = end;
            }
            other => return Err(format!("unsupported wire type {other} at byte {pos}")),
        }
    }
    Ok(())
}

/// Reads the header fields of a serialized `ModelProto`.
pub(crate) fn read_header(bytes: &[u8]) -> Result<OnnxHeader, String> {
    let mut header = OnnxHeader::default();
    let mut opsets = Vec::new();
    let mut has_graph = false;
    walk(
        bytes,
        |field, payload| {
            match field {
                7 => has_graph = true,
                8 => {
                    let mut domain = String::new();
                    let mut version = 0;
                    walk(
                        payload,
                        |f, p| {
                            if f == 1 {
                                domain = String::from_utf8_lossy(p).into_owned();
                            }
                            Ok(())
                        },
                        |f, v| {
                            if f == 2 {
                                version = v;
                            }
                        },
                    )?;
                    opsets.push((domain, version));
                }
                _ => {}
            }
            Ok(())
        },
        |field, v| {
            if field == 1 {
                header.ir_version = v;
            }
        },
    )?;
    if !has_graph {
        return Err("no graph in the model".into());
    }
    header.opsets = opsets;
    header.has_graph = has_graph;
    Ok(header)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field_varint(field: u64, v: u64) -> Vec<u8> {
        let mut out = Vec::new();
        for x in [field << 3, v] {
            let mut x = x;
            loop {
                let b = (x & 0x7f) as u8;
                x >>= 7;
                if x == 0 {
                    out.push(b);
                    break;
                }
                out.push(b | 0x80);
            }
        }
        out
    }

    fn field_bytes(field: u64, payload: &[u8]) -> Vec<u8> {
        let mut out = field_varint(field, payload.len() as u64);
        out[0] = ((field << 3) | 2) as u8;
        out.extend_from_slice(payload);
        out
    }

    #[test]
    fn reads_ir_version_and_opsets() {
        let mut opset = field_bytes(1, b"");
        opset.extend(field_varint(2, 17));
        let mut ml = field_bytes(1, b"ai.onnx.ml");
        ml.extend(field_varint(2, 3));
        let mut model = field_varint(1, 8);
        model.extend(field_bytes(8, &opset));
        model.extend(field_bytes(8, &ml));
        model.extend(field_bytes(7, b"\x0a\x01g"));
        let h = read_header(&model).unwrap();
        assert_eq!(h.ir_version, 8);
        assert_eq!(h.default_opset(), Some(17));
        assert_eq!(h.opsets.len(), 2);
        assert_eq!(h.opsets[1], ("ai.onnx.ml".to_string(), 3));
        // Truncation anywhere inside a field is an error.
        for cut in 1..model.len() - 1 {
            let r = read_header(&model[..cut]);
            assert!(r.is_err(), "cut {cut}: {r:?}");
        }
    }
}
