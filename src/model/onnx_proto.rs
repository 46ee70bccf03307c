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
fn walk<'a>(
    buf: &'a [u8],
    mut on_bytes: impl FnMut(u64, &'a [u8]) -> Result<(), String>,
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

/// One node of a graph (`NodeProto`): its operator, tensor names and integer attributes.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct OnnxNode {
    /// `op_type` (field 4).
    pub op_type: String,
    /// `domain` (field 7); empty for the default domain.
    pub domain: String,
    /// Input tensor names (field 1), in order; an empty name is an omitted optional input.
    pub inputs: Vec<String>,
    /// Output tensor names (field 2).
    pub outputs: Vec<String>,
    /// Integer attributes (`i`, field 3, or `ints`, field 8) by name; float, string and
    /// tensor attributes are listed with no values.
    pub int_attributes: Vec<(String, Vec<i64>)>,
}

impl OnnxNode {
    /// The values of the integer attribute `name`, when present.
    pub fn ints(&self, name: &str) -> Option<&[i64]> {
        self.int_attributes
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }
}

/// One initializer (`TensorProto`) of a graph.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct OnnxTensor {
    /// `name` (field 8).
    pub name: String,
    /// `dims` (field 1).
    pub dims: Vec<i64>,
    /// `data_type` (field 2); 1 is FLOAT.
    pub data_type: u64,
    /// The values of a FLOAT tensor stored inside the file (`raw_data` or packed
    /// `float_data`) whose count matches `dims`; `None` otherwise (other types, external
    /// data, or a count that does not match).
    pub floats: Option<Vec<f32>>,
}

/// The parts of a `GraphProto` a native re-implementation of a small graph needs.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct OnnxGraph {
    /// Nodes in file order (topological in a valid model).
    pub nodes: Vec<OnnxNode>,
    /// Initializers.
    pub initializers: Vec<OnnxTensor>,
    /// Names of the graph inputs (field 11).
    pub inputs: Vec<String>,
    /// Names of the graph outputs (field 12).
    pub outputs: Vec<String>,
}

impl OnnxGraph {
    /// The node that produces tensor `name`.
    pub fn producer(&self, name: &str) -> Option<&OnnxNode> {
        self.nodes
            .iter()
            .find(|n| n.outputs.iter().any(|o| o == name))
    }

    /// The initializer called `name`.
    pub fn initializer(&self, name: &str) -> Option<&OnnxTensor> {
        self.initializers.iter().find(|t| t.name == name)
    }
}

fn utf8(p: &[u8]) -> String {
    String::from_utf8_lossy(p).into_owned()
}

/// Packed varints (a repeated integer field written as one length-delimited payload).
fn packed_varints(payload: &[u8], out: &mut Vec<i64>) -> Result<(), String> {
    let mut pos = 0;
    while pos < payload.len() {
        // int64 values travel as two's complement varints.
        out.push(varint(payload, &mut pos)? as i64);
    }
    Ok(())
}

fn read_node(buf: &[u8]) -> Result<OnnxNode, String> {
    let mut node = OnnxNode::default();
    walk(
        buf,
        |field, p| {
            match field {
                1 => node.inputs.push(utf8(p)),
                2 => node.outputs.push(utf8(p)),
                4 => node.op_type = utf8(p),
                7 => node.domain = utf8(p),
                5 => {
                    let mut name = String::new();
                    // `ints` may come packed (one payload) or as single varints, as `i`.
                    let (mut packed, mut single) = (Vec::new(), Vec::new());
                    walk(
                        p,
                        |f, q| {
                            match f {
                                1 => name = utf8(q),
                                8 => packed_varints(q, &mut packed)?,
                                _ => {}
                            }
                            Ok(())
                        },
                        |f, v| {
                            if f == 3 || f == 8 {
                                single.push(v as i64);
                            }
                        },
                    )?;
                    packed.extend(single);
                    node.int_attributes.push((name, packed));
                }
                _ => {}
            }
            Ok(())
        },
        |_, _| {},
    )?;
    Ok(node)
}

fn read_tensor(buf: &[u8]) -> Result<OnnxTensor, String> {
    let mut t = OnnxTensor::default();
    let mut raw: Option<&[u8]> = None;
    let mut packed_floats: Option<&[u8]> = None;
    let mut external = false;
    let (mut dims_single, mut data_type) = (Vec::new(), 0);
    walk(
        buf,
        |field, p| {
            match field {
                1 => packed_varints(p, &mut t.dims)?,
                4 => packed_floats = Some(p),
                8 => t.name = utf8(p),
                9 => raw = Some(p),
                _ => {}
            }
            Ok(())
        },
        |field, v| match field {
            1 => dims_single.push(v as i64),
            2 => data_type = v,
            14 => external = v == 1,
            _ => {}
        },
    )?;
    t.dims.extend(dims_single);
    t.data_type = data_type;
    let count = t.dims.iter().try_fold(1usize, |acc, &d| {
        usize::try_from(d).ok().and_then(|d| acc.checked_mul(d))
    });
    if t.data_type == 1
        && !external
        && let (Some(count), Some(bytes)) = (count, raw.or(packed_floats))
        && count.checked_mul(4) == Some(bytes.len())
    {
        t.floats = Some(
            bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        );
    }
    Ok(t)
}

/// The payload of the last length-delimited field `wanted` of a message, if any.
fn bytes_field(buf: &[u8], wanted: u64) -> Result<Option<&[u8]>, String> {
    let mut found = None;
    walk(
        buf,
        |field, p| {
            if field == wanted {
                found = Some(p);
            }
            Ok(())
        },
        |_, _| {},
    )?;
    Ok(found)
}

/// Reads the graph of a serialized `ModelProto`: nodes, initializers, input and output
/// names. Subgraphs inside attributes are not read.
pub(crate) fn read_graph(bytes: &[u8]) -> Result<OnnxGraph, String> {
    let buf = bytes_field(bytes, 7)?.ok_or_else(|| "no graph in the model".to_string())?;
    let mut graph = OnnxGraph::default();
    walk(
        buf,
        |field, p| {
            match field {
                1 => graph.nodes.push(read_node(p)?),
                5 => graph.initializers.push(read_tensor(p)?),
                11 | 12 => {
                    // ValueInfoProto: name is field 1.
                    let name = bytes_field(p, 1)?.map(utf8).unwrap_or_default();
                    if field == 11 {
                        graph.inputs.push(name);
                    } else {
                        graph.outputs.push(name);
                    }
                }
                _ => {}
            }
            Ok(())
        },
        |_, _| {},
    )?;
    Ok(graph)
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
