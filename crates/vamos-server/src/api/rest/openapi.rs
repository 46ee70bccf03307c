//! The OpenAPI 3.0 document of the REST API (`GET /openapi.json`, `vamos openapi`), built
//! from the code: the routes and who may call them from [`ROUTES`], each operation's text,
//! parameters, bodies and answers from [`operation`], and every JSON body's schema from
//! the Rust type the handler reads or writes (schemars, following the types' serde
//! attributes and doc comments). Nothing is written twice: a route without an operation,
//! or an operation whose answer is an untyped object, fails the unit tests.
//!
//! The schemas follow the deserialising contract (a field with a default is optional),
//! so one schema per type serves both directions: what the server writes always reads
//! back as the same type.

use super::calibration::{JobCancelling, JobList, JobStarted, NominalList};
use super::episodes::{EpisodeScores, ScoreQuery};
use super::errors::ErrorBody;
use super::health::{Health, ModelReady};
use super::kserve::{ModelMetadata, ServerMetadata};
use super::live::{
    AlarmList, AlarmQuery, LiveQuery, LiveSnapshot, MarkBody, Timeline, TimelineQuery, Whoami,
};
use super::models::{ActiveModel, ActiveRequest, ModelList, ModelUploaded};
use super::profiles::{ProfileList, ProfileView};
use super::robots::{RobotList, RobotQuery};
use super::sessions::{SessionList, SessionReloaded, StoreStatus};
use super::{Access, ROUTES};
use crate::session::calibration::CalibrationRequest;
use crate::store::{AlarmRecord, JobInfo, ModelInfo, ProfileSpec, RobotInfo, ThresholdsPatch};
use schemars::JsonSchema;
use schemars::generate::{SchemaGenerator, SchemaSettings};
use serde_json::{Map, Value, json};
use std::sync::LazyLock;

/// The document, serialised once.
static DOCUMENT: LazyLock<String> = LazyLock::new(|| document().to_string());

/// The document as `GET /openapi.json` serves it.
pub fn document_json() -> &'static str {
    &DOCUMENT
}

/// The 429 of an upload.
const UPLOAD_BUSY: &str = "Too many uploads in progress (max_uploads) or the upload disk \
                           budget spent (max_upload_disk_mb), checked before the body is \
                           read: retry later";

/// An object name in the data directory (models, robots, profiles).
const NAME_RULE: &str = "1 to 64 of A-Z a-z 0-9 . _ -, not starting with .";

/// Builds the document.
pub fn document() -> Value {
    let mut generator = SchemaSettings::openapi3().into_generator();
    let mut paths = Map::new();
    for &(method, path, access) in ROUTES {
        let Some(op) = operation(method, path, &mut generator) else {
            // Caught by the unit test; a served document leaves the route out.
            continue;
        };
        let entry = paths
            .entry(path.to_string())
            .or_insert_with(|| Value::Object(Map::new()));
        entry[method.to_ascii_lowercase()] = op.into_json(path, access);
    }
    // Every error answer refers to it.
    schema::<ErrorBody>(&mut generator);
    let mut schemas = generator.take_definitions(true);
    schemas.values_mut().for_each(for_json_readers);
    schemas.insert(
        "Name".into(),
        json!({
            "type": "string", "minLength": 1, "maxLength": 64,
            "pattern": "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,63}$",
            "description": format!("Object name: {NAME_RULE}"),
        }),
    );
    json!({
        "openapi": "3.0.3",
        "info": {
            "title": "vamos REST API",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "Visual anomaly monitoring service: health, metrics, sessions, \
                episode scoring, and administration of models, robots, profiles and \
                calibration jobs; the live view (/ui) and alarms. Errors are \
                {\"error\": message}. Generated from the server's code.",
        },
        "paths": paths,
        "components": {
            "schemas": schemas,
            "securitySchemes": {
                "bearer": {
                    "type": "http", "scheme": "bearer",
                    "description": "A viewer, robot or admin token (required only when tokens are configured)",
                },
            },
            "responses": {
                "Unauthorized": error_response("No or unknown token"),
                "Forbidden": error_response("The token's role may not call this route"),
            },
        },
    })
}

/// The schemas as JSON readers and client generators take them: in descriptions (the
/// types' doc comments) `None` is `null` and rustdoc's links (``[`Type`]``) are plain
/// code; a member whose type is another schema keeps no whole-object default (that
/// schema's members carry their own defaults; generators refuse a default beside a
/// reference).
fn for_json_readers(v: &mut Value) {
    collapse_string_enum(v);
    match v {
        Value::Object(m) => {
            if m.contains_key("allOf") && m.get("default").is_some_and(|d| !d.is_null()) {
                m.remove("default");
            }
            if let Some(Value::String(d)) = m.get_mut("description") {
                *d = d
                    .replace("`None`", "`null`")
                    .replace("[`", "`")
                    .replace("`]", "`");
            }
            m.values_mut().for_each(for_json_readers);
        }
        Value::Array(a) => a.iter_mut().for_each(for_json_readers),
        _ => {}
    }
}

/// A `oneOf` of single strings (what schemars writes for an enum of unit variants with
/// their doc comments) as one string `enum`, each value's text listed in the description:
/// generators make one enum type of it.
fn collapse_string_enum(v: &mut Value) {
    let Some(variants) = v.get("oneOf").and_then(Value::as_array) else {
        return;
    };
    let mut values = Vec::new();
    let mut notes = Vec::new();
    for variant in variants {
        match (variant["type"].as_str(), variant["enum"].as_array()) {
            (Some("string"), Some(e)) if e.len() == 1 && e[0].is_string() => {
                values.push(e[0].clone());
                if let Some(d) = variant["description"].as_str() {
                    notes.push(format!("- `{}`: {}", e[0].as_str().unwrap_or(""), d));
                }
            }
            _ => return,
        }
    }
    let Some(m) = v.as_object_mut() else { return };
    m.remove("oneOf");
    m.insert("type".into(), json!("string"));
    m.insert("enum".into(), Value::Array(values));
    if !notes.is_empty() {
        let head = m.get("description").and_then(Value::as_str).unwrap_or("");
        let text = format!("{head}\n\n{}", notes.join("\n")).trim().to_string();
        m.insert("description".into(), json!(text));
    }
}

fn error_response(description: &str) -> Value {
    json!({
        "description": description,
        "content": { "application/json": { "schema": { "$ref": "#/components/schemas/ErrorBody" } } },
    })
}

/// The schema of `T` as a JSON value (a `$ref` for a named type).
fn schema<T: JsonSchema>(generator: &mut SchemaGenerator) -> Value {
    generator.subschema_for::<T>().to_value()
}

/// `{"type": "string", "format": "binary"}`.
fn binary() -> Value {
    json!({ "type": "string", "format": "binary" })
}

/// One operation's documentation.
struct Op {
    summary: &'static str,
    description: Option<&'static str>,
    params: Vec<Value>,
    body: Option<Value>,
    responses: Map<String, Value>,
}

impl Op {
    fn new(summary: &'static str) -> Op {
        Op {
            summary,
            description: None,
            params: Vec::new(),
            body: None,
            responses: Map::new(),
        }
    }

    fn describe(mut self, description: &'static str) -> Op {
        self.description = Some(description);
        self
    }

    /// Query parameters: the fields of `Q` (what the handler's `Query<Q>` reads).
    fn query<Q: JsonSchema>(mut self) -> Op {
        let root = SchemaSettings::openapi3()
            .with(|s| s.inline_subschemas = true)
            .into_generator()
            .into_root_schema_for::<Q>();
        let required: Vec<&str> = root
            .get("required")
            .and_then(Value::as_array)
            .map(|r| r.iter().filter_map(Value::as_str).collect())
            .unwrap_or_default();
        let properties = root.get("properties").and_then(Value::as_object);
        for (name, field) in properties.into_iter().flatten() {
            let mut field = field.clone();
            let description = field
                .as_object_mut()
                .and_then(|f| f.remove("description"))
                .unwrap_or(Value::Null);
            self.params.push(json!({
                "name": name,
                "in": "query",
                "required": required.contains(&name.as_str()),
                "description": description,
                "schema": field,
            }));
        }
        self
    }

    /// A JSON body of type `T`.
    fn json_body<T: JsonSchema>(
        mut self,
        generator: &mut SchemaGenerator,
        required: bool,
        description: &str,
    ) -> Op {
        self.body = Some(json!({
            "required": required,
            "description": description,
            "content": { "application/json": { "schema": schema::<T>(generator) } },
        }));
        self
    }

    /// A body of bytes (an upload).
    fn bytes_body(mut self, description: &str) -> Op {
        self.body = Some(json!({
            "required": true,
            "description": description,
            "content": { "application/octet-stream": { "schema": binary() } },
        }));
        self
    }

    /// A JSON answer of type `T`.
    fn ok<T: JsonSchema>(
        self,
        generator: &mut SchemaGenerator,
        status: u16,
        description: &str,
    ) -> Op {
        let content = json!({ "application/json": { "schema": schema::<T>(generator) } });
        self.answer(status, description, Some(content))
    }

    /// An answer with `content` (media type to `{"schema": ..}`), or without a body.
    fn answer(mut self, status: u16, description: &str, content: Option<Value>) -> Op {
        let mut r = json!({ "description": description });
        if let Some(content) = content {
            r["content"] = content;
        }
        self.responses.insert(status.to_string(), r);
        self
    }

    /// An error answer (`{"error": message}`).
    fn error(mut self, status: u16, description: &str) -> Op {
        self.responses
            .insert(status.to_string(), error_response(description));
        self
    }

    /// Error answers with their usual meaning ([`super::errors`]).
    fn errors(self, statuses: &[u16]) -> Op {
        statuses.iter().fold(self, |op, &status| {
            let description = match status {
                400 => "Refused: a bad name, parameter or body",
                404 => "Unknown",
                409 => "In use, or in a state that does not allow it",
                413 => "Too large",
                429 => "Busy: retry later",
                500 => "Internal error",
                507 => "The data directory is full",
                _ => "Error",
            };
            op.error(status, description)
        })
    }

    /// The operation object of `path` (its path parameters from [`path_param`]) for
    /// callers with `access`.
    fn into_json(self, path: &str, access: Access) -> Value {
        let mut params: Vec<Value> = placeholders(path)
            .map(|name| path_param(path, name))
            .collect();
        params.extend(self.params);
        let mut responses = self.responses;
        let role = match access {
            Access::Open => None,
            Access::Viewer => Some("viewer"),
            Access::Robot => Some("robot"),
            Access::Admin => Some("admin"),
        };
        let mut op = json!({ "summary": self.summary });
        if let Some(d) = self.description {
            op["description"] = json!(d);
        }
        if !params.is_empty() {
            op["parameters"] = json!(params);
        }
        if let Some(body) = self.body {
            op["requestBody"] = body;
        }
        match role {
            None => op["security"] = json!([]),
            Some(role) => {
                op["security"] = json!([{ "bearer": [] }]);
                op["x-vamos-role"] = json!(role);
                responses.insert(
                    "401".into(),
                    json!({ "$ref": "#/components/responses/Unauthorized" }),
                );
                responses.insert(
                    "403".into(),
                    json!({ "$ref": "#/components/responses/Forbidden" }),
                );
            }
        }
        op["responses"] = Value::Object(responses);
        op
    }
}

/// The `{name}` placeholders of a path, in order.
fn placeholders(path: &str) -> impl Iterator<Item = &str> {
    path.split('/')
        .filter_map(|seg| seg.strip_prefix('{').and_then(|s| s.strip_suffix('}')))
}

/// A path parameter: what `{name}`, `{version}`, `{id}` or `{asset}` means in `path`.
fn path_param(path: &str, name: &str) -> Value {
    let name_ref = json!({ "$ref": "#/components/schemas/Name" });
    let id = json!({ "type": "string", "minLength": 1, "maxLength": 200 });
    let kserve = path.starts_with("/v2/");
    let (description, schema) = match name {
        "name" if kserve => (
            "A profile or a stored model (KServe model name)".to_string(),
            json!({ "type": "string" }),
        ),
        "name" if path.starts_with("/v1/profiles") => {
            (format!("Profile name: {NAME_RULE}"), name_ref)
        }
        "name" => (format!("Object name: {NAME_RULE}"), name_ref),
        "version" if kserve => (
            "A stored model version (decimal)".to_string(),
            json!({ "type": "string" }),
        ),
        "version" => (
            "Version number".to_string(),
            json!({ "type": "integer", "minimum": 1, "maximum": u32::MAX }),
        ),
        "id" if path.starts_with("/v1/jobs") => (
            "Job id".to_string(),
            json!({ "type": "integer", "minimum": 0 }),
        ),
        "id" if path.starts_with("/v1/alarms") => ("Alarm id".to_string(), id),
        "id" => ("Session id".to_string(), id),
        "asset" => (
            "File name (app.js, app.css, docs.js, docs.css)".to_string(),
            json!({ "type": "string", "minLength": 1, "maxLength": 200 }),
        ),
        other => (other.to_string(), json!({ "type": "string" })),
    };
    json!({
        "name": name, "in": "path", "required": true,
        "description": description, "schema": schema,
    })
}

/// What is served for a PNG answer.
fn png() -> Option<Value> {
    Some(json!({ "image/png": { "schema": binary() } }))
}

/// The documentation of a route of [`ROUTES`] (`None`: not documented, a test failure).
fn operation(method: &str, path: &str, g: &mut SchemaGenerator) -> Option<Op> {
    Some(match (method, path) {
        ("GET", "/healthz") => Op::new("Liveness").ok::<Health>(g, 200, "Live"),
        ("GET", "/readyz") => {
            Op::new("Readiness: listeners bound, a scoring worker alive, not stopping")
                .ok::<Health>(g, 200, "Ready")
                .ok::<Health>(g, 503, "Not ready")
        }
        ("GET", "/v2/health/live") => Op::new("KServe v2 liveness").ok::<Health>(g, 200, "Live"),
        ("GET", "/v2/health/ready") => Op::new("KServe v2 readiness")
            .ok::<Health>(g, 200, "Ready")
            .ok::<Health>(g, 503, "Not ready"),
        ("GET", "/v2/models/{name}/ready") => Op::new(
            "KServe v2 model readiness, for the names /v2/models/{name} describes: a profile \
             that loads (a stored one is loaded here, as the first session would), or a \
             stored model whose active version is served",
        )
        .ok::<ModelReady>(g, 200, "Ready")
        .ok::<ModelReady>(g, 503, "Known but not ready")
        .ok::<ModelReady>(g, 404, "No profile or model of that name"),
        ("GET", "/v2") => {
            Op::new("KServe v2 server metadata").ok::<ServerMetadata>(g, 200, "Server metadata")
        }
        ("GET", "/v2/models/{name}") => Op::new(
            "KServe v2 model metadata: a profile (platform vamos_profile, no versions) or, \
             when no profile has the name, a stored model (platform vamos_bundle, its served \
             versions)",
        )
        .ok::<ModelMetadata>(g, 200, "Model metadata")
        .errors(&[404]),
        ("GET", "/v2/models/{name}/versions/{version}") => {
            Op::new("KServe v2 metadata of one served version of a stored model")
                .ok::<ModelMetadata>(g, 200, "Model metadata")
                .errors(&[404])
        }
        ("GET", "/v2/models/{name}/versions/{version}/ready") => Op::new(
            "KServe v2 readiness of one version of a stored model: stored, checksum \
             verified, loaded with ONNX Runtime at upload",
        )
        .ok::<ModelReady>(g, 200, "Ready")
        .ok::<ModelReady>(g, 404, "Not ready"),
        ("GET", "/metrics") => Op::new("Prometheus metrics").answer(
            200,
            "Text exposition format 0.0.4",
            Some(json!({ "text/plain": { "schema": { "type": "string" } } })),
        ),
        ("GET", "/openapi.json") => Op::new("This description").answer(
            200,
            "OpenAPI 3.0 document",
            Some(json!({ "application/json": { "schema": {
                "type": "object",
                "required": ["openapi", "info", "paths"],
                "properties": {
                    "openapi": { "type": "string" },
                    "info": { "type": "object" },
                    "paths": { "type": "object" },
                    "components": { "type": "object" },
                },
            } } })),
        ),
        ("GET", "/v1/sessions") => {
            Op::new("Sessions open now").ok::<SessionList>(g, 200, "Sessions")
        }
        ("GET", "/v1/store") => Op::new(
            "The data directory and, in a fleet, the shared store: role, URL, generation, \
             last sync, last error",
        )
        .ok::<StoreStatus>(g, 200, "Store status"),
        ("POST", "/v1/sessions/{id}/reload") => Op::new(
            "Move a running session to its profile as stored now (new active model \
             version, thresholds, calibration) from its next frame; its flow predictor \
             warms up again and the stream gets a KIND_RELOADED event",
        )
        .ok::<SessionReloaded>(g, 200, "Moved, or nothing changed since it opened")
        .errors(&[404, 409]),
        ("POST", "/v1/episodes:score") => Op::new(
            "Score a recorded episode (MCAP, or zstd-compressed MCAP) with a profile; JSON \
             scores, or a scored MCAP with Accept: application/x-mcap",
        )
        .query::<ScoreQuery>()
        .bytes_body("The episode: a ROS 2 bag in MCAP")
        .answer(
            200,
            "Scores; with Accept: application/x-mcap the input's images plus /vamos/score, \
             /vamos/anomaly and each detector's topic as a ROS 2 MCAP bag (header \
             x-vamos-damage when the file was cut short)",
            Some(json!({
                "application/json": { "schema": schema::<EpisodeScores>(g) },
                "application/x-mcap": { "schema": binary() },
            })),
        )
        .error(413, "Episode too large (max_episode_bytes)")
        .error(
            429,
            "Server busy: no session place (max_sessions), too many uploads (max_uploads) \
             or the upload disk budget spent, checked before the body is read",
        )
        .errors(&[400, 404]),
        ("GET", "/v1/models") => Op::new("Stored models").ok::<ModelList>(g, 200, "Models"),
        ("GET", "/v1/models/{name}") => Op::new("A stored model and its versions")
            .ok::<ModelInfo>(g, 200, "The model")
            .errors(&[400, 404]),
        ("PUT", "/v1/models/{name}") => Op::new(
            "Upload a model bundle as the model's next version (validated: bundle, \
             checksums, loads with ONNX Runtime; refused uploads store nothing)",
        )
        .bytes_body("The model bundle (vamos-train export)")
        .ok::<ModelUploaded>(g, 201, "The version stored")
        .error(413, "Bundle larger than max_model_bytes")
        .error(429, UPLOAD_BUSY)
        .errors(&[400, 500]),
        ("DELETE", "/v1/models/{name}") => {
            Op::new("Delete a model with all its versions (refused while a profile uses it)")
                .answer(204, "Deleted", None)
                .errors(&[400, 404, 409])
        }
        ("DELETE", "/v1/models/{name}/versions/{version}") => Op::new("Delete one model version")
            .answer(204, "Deleted", None)
            .errors(&[400, 404, 409]),
        ("POST", "/v1/models/{name}/active") => Op::new(
            "Make a version active: new sessions of profiles following the model use it; \
             running sessions keep theirs unless reload_sessions is true",
        )
        .json_body::<ActiveRequest>(g, true, "The version")
        .ok::<ActiveModel>(g, 200, "The model")
        .errors(&[400, 404]),
        ("GET", "/v1/robots") => Op::new("Stored robots").ok::<RobotList>(g, 200, "Robots"),
        ("GET", "/v1/robots/{name}") => Op::new("A stored robot")
            .ok::<RobotInfo>(g, 200, "The robot")
            .errors(&[400, 404]),
        ("PUT", "/v1/robots/{name}") => Op::new(
            "Upload (or replace) a robot: a URDF file, or a .tar.gz/.zip package; format \
             from ?format= or Content-Type (application/gzip, application/zip, \
             application/xml, text/xml)",
        )
        .query::<RobotQuery>()
        .bytes_body("The URDF file or package archive")
        .ok::<RobotInfo>(g, 201, "The robot stored")
        .error(413, "Package larger than max_robot_bytes")
        .error(429, UPLOAD_BUSY)
        .errors(&[400, 500]),
        ("DELETE", "/v1/robots/{name}") => {
            Op::new("Delete a robot (refused while a profile uses it)")
                .answer(204, "Deleted", None)
                .errors(&[400, 404, 409])
        }
        ("GET", "/v1/profiles") => {
            Op::new("Profiles: the server's profile files, then the stored profiles")
                .describe(
                    "A stored profile's calibration statistics that run large (the per-cell \
                 statistics in `thresholds.scene` and `thresholds.flow`, the kinematic \
                 novelty's nominal states in `thresholds.kinematics`, a learned depth's \
                 views in `thresholds.depth`) are listed by their sizes only (StatsSummary), with a `detail` saying so; \
                 `GET /v1/profiles/{name}` gives them whole.",
                )
                .ok::<ProfileList>(g, 200, "Profiles")
        }
        ("GET", "/v1/profiles/{name}") => Op::new("A profile")
            .ok::<ProfileView>(g, 200, "The profile; a stored one also carries `profile`")
            .errors(&[400, 404]),
        ("PUT", "/v1/profiles/{name}") => {
            Op::new("Create or replace a stored profile, then load it")
                .json_body::<ProfileSpec>(g, true, "What the profile binds")
                .ok::<ProfileView>(g, 200, "The profile, with load_error when it does not load")
                .errors(&[400, 404, 409])
        }
        ("DELETE", "/v1/profiles/{name}") => Op::new("Delete a stored profile")
            .answer(204, "Deleted", None)
            .errors(&[400, 404, 409]),
        ("PATCH", "/v1/profiles/{name}/thresholds") => {
            Op::new("Change threshold overrides: a number sets, null clears, absent leaves")
                .json_body::<ThresholdsPatch>(g, true, "The changes")
                .ok::<ProfileView>(g, 200, "The profile")
                .errors(&[400, 404, 409])
        }
        ("POST", "/v1/profiles/{name}/calibrate") => Op::new(
            "Start a calibration job over nominal episodes: paths on the server (JSON: files \
             or folders of .mcap) or uploaded with the request (multipart/form-data). A \
             profile file's calibration is kept in the data directory, in force over the \
             file's own (the file is not written)",
        )
        .json_body::<CalibrationRequest>(
            g,
            true,
            "Episodes: server paths (JSON) or uploaded files (multipart)",
        )
        .multipart_calibration()
        .ok::<JobStarted>(g, 202, "Started")
        .errors(&[400, 404, 409, 413, 429]),
        ("GET", "/v1/profiles/{name}/nominal") => Op::new(
            "The profile's nominal set: the kept recordings of sessions with an alarm marked \
             as a false alarm",
        )
        .ok::<NominalList>(g, 200, "Nominal set")
        .errors(&[400]),
        ("POST", "/v1/profiles/{name}/recalibrate") => Op::new(
            "Start a recalibration from the profile's nominal set: the episodes are scored \
             with the profile as it is and the job's record gets a proposal (thresholds now \
             and proposed); nothing changes until it is applied",
        )
        .ok::<JobStarted>(g, 202, "Started")
        .error(
            409,
            "Not calibrated, or no finished episode in its nominal set",
        )
        .error(429, "max_jobs jobs are running")
        .errors(&[404]),
        ("GET", "/v1/jobs") => Op::new(
            "Calibration jobs, oldest first (kept in the data directory: a job that was \
             running when the server stopped shows as failed)",
        )
        .describe(
            "A job's calibration statistics that run large (`calibration.thresholds.scene`, \
             `.flow`, `.kinematics` and `.depth`) are listed by their sizes only (StatsSummary), with \
             a `detail` saying so; `GET /v1/jobs/{id}` gives them whole.",
        )
        .ok::<JobList>(g, 200, "Jobs"),
        ("GET", "/v1/jobs/{id}") => Op::new("A job")
            .ok::<JobInfo>(g, 200, "The job")
            .errors(&[404]),
        ("DELETE", "/v1/jobs/{id}") => Op::new(
            "Cancel a running job (202; it stops before its next episode and ends \
             cancelled) or remove a finished job's record (204)",
        )
        .ok::<JobCancelling>(g, 202, "Cancelling")
        .answer(204, "Removed", None)
        .errors(&[404]),
        ("POST", "/v1/jobs/{id}/apply") => Op::new(
            "Apply a finished recalibration's proposal: its calibration becomes the profile's",
        )
        .ok::<JobInfo>(g, 200, "The job, its proposal marked applied")
        .error(
            409,
            "Not a finished recalibration, applied already, or the profile was calibrated \
             again since",
        )
        .errors(&[404]),
        ("GET", "/ui") => {
            Op::new("The live view (HTML page; it asks for a token and reads the API with it)")
                .answer(
                    200,
                    "The page",
                    Some(json!({ "text/html": { "schema": { "type": "string" } } })),
                )
        }
        ("GET", "/docs") => Op::new(
            "This API's reference page (HTML; it reads /openapi.json): every operation, who \
             may call it, its parameters, bodies and answers, and every schema",
        )
        .answer(
            200,
            "The page",
            Some(json!({ "text/html": { "schema": { "type": "string" } } })),
        ),
        ("GET", "/ui/{asset}") => Op::new(
            "An asset of the live view or the reference page (app.js, app.css, docs.js, docs.css)",
        )
        .answer(
            200,
            "The asset",
            Some(json!({
                "text/javascript": { "schema": { "type": "string" } },
                "text/css": { "schema": { "type": "string" } },
            })),
        )
        .errors(&[404]),
        ("GET", "/v1/whoami") => Op::new("The caller's role").ok::<Whoami>(g, 200, "Role"),
        ("GET", "/v1/live") => Op::new(
            "Live sessions, the robots with their open and last ended sessions, and a \
             session's new timeline points and alarms (an ended one's whole run): \
             server-sent events every 0.5 s with Accept: text/event-stream (events \
             sessions, robots, timeline, alarms, gone: each event's data is the snapshot's \
             member of that name), else one JSON snapshot",
        )
        .query::<LiveQuery>()
        .answer(
            200,
            "Event stream or snapshot",
            Some(json!({
                "text/event-stream": { "schema": { "type": "string" } },
                "application/json": { "schema": schema::<LiveSnapshot>(g) },
            })),
        )
        .errors(&[400]),
        ("GET", "/v1/alarms") => Op::new(
            "Recent alarms of every session (newest first), or with marked=true the stored \
             false alarms",
        )
        .query::<AlarmQuery>()
        .ok::<AlarmList>(g, 200, "Alarms")
        .errors(&[400]),
        ("GET", "/v1/alarms/{id}") => Op::new("An alarm (recent, or stored as a false alarm)")
            .ok::<AlarmRecord>(g, 200, "The alarm")
            .errors(&[404]),
        ("GET", "/v1/alarms/{id}/thumbnail") => {
            Op::new("The frame at the alarm's start (recent alarms)")
                .answer(200, "PNG image (8-bit gray)", png())
                .errors(&[404])
        }
        ("POST", "/v1/alarms/{id}/false-alarm") => Op::new(
            "Mark an alarm as a false alarm (stored in the data directory; a viewer token is \
             refused)",
        )
        .json_body::<MarkBody>(g, false, "An optional note")
        .ok::<AlarmRecord>(g, 200, "The marked alarm")
        .errors(&[400, 404, 409, 507]),
        ("GET", "/v1/sessions/{id}/alarms") => Op::new(
            "A session's recent alarms (an ended session's kept ones), newest first",
        )
            .ok::<AlarmList>(g, 200, "Alarms")
            .errors(&[404]),
        ("GET", "/v1/sessions/{id}/timeline") => Op::new(
            "A session's timeline (an open session's last 600 frames, an ended one's whole \
             run in at most 256 points): each detector's value, the thresholds in force, the \
             summary",
        )
        .query::<TimelineQuery>()
        .ok::<Timeline>(g, 200, "Timeline")
        .errors(&[400, 404]),
        ("GET", "/v1/sessions/{id}/frame") => {
            Op::new("A session's latest frame, shrunk to at most 160 px wide")
                .answer(200, "PNG image (8-bit gray)", png())
                .errors(&[404])
        }
        ("GET", "/v1/sessions/{id}/map") => Op::new("A session's latest anomaly map (0 = nominal)")
            .answer(200, "PNG image (8-bit gray)", png())
            .errors(&[404]),
        _ => return None,
    })
}

impl Op {
    /// The `multipart/form-data` form of a calibration request, beside its JSON form.
    fn multipart_calibration(mut self) -> Op {
        let files = |description: &str| json!({ "type": "array", "items": binary(), "description": description });
        if let Some(body) = self.body.as_mut() {
            body["content"]["multipart/form-data"] = json!({ "schema": {
                "type": "object",
                "required": ["episodes"],
                "properties": {
                    "episodes": files(
                        "Nominal training episodes (.mcap), one file part each; each is \
                         named after its file name's stem",
                    ),
                    "holdout": files("Held-out nominal episodes for the conformal threshold"),
                    "alpha": { "type": "number", "default": 0.1, "description": "Conformal miscoverage level, in (0, 1)" },
                },
            } });
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeSet;

    fn refs(v: &Value, out: &mut BTreeSet<String>) {
        match v {
            Value::Object(m) => {
                if let Some(r) = m.get("$ref").and_then(Value::as_str) {
                    out.insert(r.to_string());
                }
                m.values().for_each(|x| refs(x, out));
            }
            Value::Array(a) => a.iter().for_each(|x| refs(x, out)),
            _ => {}
        }
    }

    #[test]
    fn every_route_is_documented_with_its_role_and_path_parameters() {
        let doc = document();
        let mut described = BTreeSet::new();
        for (path, ops) in doc["paths"].as_object().unwrap() {
            for (method, op) in ops.as_object().unwrap() {
                let method = method.to_ascii_uppercase();
                let access = ROUTES
                    .iter()
                    .find(|(m, p, _)| *m == method && p == path)
                    .map(|r| r.2)
                    .unwrap_or_else(|| panic!("{method} {path} is described but not routed"));
                let role = op.get("x-vamos-role").and_then(Value::as_str);
                assert_eq!(role.is_none(), access == Access::Open, "{method} {path}");
                let in_path: Vec<&str> = op["parameters"]
                    .as_array()
                    .map(|ps| {
                        ps.iter()
                            .filter(|p| p["in"] == "path")
                            .filter_map(|p| p["name"].as_str())
                            .collect()
                    })
                    .unwrap_or_default();
                assert_eq!(in_path, placeholders(path).collect::<Vec<_>>());
                described.insert((method, path.clone()));
            }
        }
        let routed: BTreeSet<(String, String)> = ROUTES
            .iter()
            .map(|(m, p, _)| (m.to_string(), p.to_string()))
            .collect();
        assert_eq!(routed.len(), ROUTES.len(), "a route is listed twice");
        assert_eq!(described, routed);
    }

    #[test]
    fn every_json_answer_and_body_is_typed_and_every_reference_resolves() {
        let doc = document();
        let schemas = doc["components"]["schemas"].as_object().unwrap();
        let mut found = BTreeSet::new();
        refs(&doc, &mut found);
        for r in &found {
            let name = r
                .strip_prefix("#/components/schemas/")
                .or_else(|| r.strip_prefix("#/components/responses/"))
                .unwrap_or_else(|| panic!("unexpected reference {r}"));
            assert!(
                schemas.contains_key(name) || doc["components"]["responses"].get(name).is_some(),
                "{r} does not resolve"
            );
        }
        let mut typed = 0;
        for (path, ops) in doc["paths"].as_object().unwrap() {
            for (method, op) in ops.as_object().unwrap() {
                let answers = op["responses"].as_object().unwrap();
                assert!(
                    answers.keys().any(|s| s.starts_with('2')),
                    "{method} {path}"
                );
                let bodies = answers
                    .values()
                    .chain(op.get("requestBody"))
                    .filter_map(|r| r.pointer("/content/application~1json/schema"));
                for s in bodies {
                    // A reference to a generated schema, or an object with its members.
                    let ok = s.get("$ref").is_some() || s.get("properties").is_some();
                    assert!(ok, "{method} {path}: untyped JSON {s}");
                    typed += 1;
                }
            }
        }
        assert!(typed >= 50, "{typed} typed JSON bodies");
    }

    #[test]
    fn generated_schemas_follow_the_types() {
        let doc = document();
        let s = &doc["components"]["schemas"];
        // Field docs become descriptions; serde's renames and defaults are followed.
        assert_eq!(s["ProfileSource"]["enum"], json!(["file", "store"]));
        let text = s["ProfileSource"]["description"].as_str().unwrap();
        assert!(text.contains("- `store`: The data directory."), "{text}");
        assert!(s["ProfileSpec"]["properties"]["pipeline"].is_object());
        assert_eq!(s["PipelineConfig"]["additionalProperties"], json!(false));
        let required = s["ScoreJson"]["required"].as_array().unwrap();
        assert!(required.contains(&json!("stamp_ns")));
        assert!(s["ErrorBody"]["properties"]["error"]["type"] == "string");
        // A bulky statistic: whole, or the summary lists show.
        let scene = s["Thresholds"]["properties"]["scene"].to_string();
        assert!(scene.contains("CellStatsOrSummary"), "{scene}");
        let either = s["CellStatsOrSummary"]["anyOf"].to_string();
        assert!(
            either.contains("/CellStats\"") && either.contains("/StatsSummary\""),
            "{either}"
        );
    }
}
