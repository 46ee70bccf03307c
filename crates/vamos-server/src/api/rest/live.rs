//! The live view's data: alarms (list, one, the frame thumbnail at its start, marking a
//! false alarm), a session's timeline, latest frame and anomaly map, the caller's role,
//! and `GET /v1/live`, a server-sent-event stream of the session list and the robots
//! (each robot's open sessions and its last ended ones, [`crate::session::history`]),
//! and, with `?session=ID`, that session's new timeline points and alarms, every half
//! second. An ended session's timeline (its whole run, downsampled) and alarms are
//! served as an open one's are, until the history's bounds drop it.
//!
//! Authentication is the REST one: a bearer token in the `authorization` header, so the
//! page reads the event stream with `fetch` (a streamed body), not `EventSource` (which
//! cannot send headers); no token ever travels in a URL.

use super::body::ApiQuery;
use super::errors::ApiError;
use crate::api::auth::{Caller, Role};
use crate::api::state::Shared;
use crate::session::SessionError;
use crate::session::SessionSummary;
use crate::session::alarms::mark_false_alarm;
use crate::session::history::EndedSession;
use crate::session::live::FramePoint;
use crate::store::AlarmRecord;
use axum::Json;
use axum::extract::{Extension, Path, State};
use axum::http::{HeaderMap, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::stream::Stream;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

/// How often `GET /v1/live` sends.
const LIVE_PERIOD: Duration = Duration::from_millis(500);

/// `?session=&marked=&profile=` of the alarm list.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct AlarmQuery {
    /// Only this session's alarms.
    session: Option<String>,
    /// The stored false alarms (oldest mark first) instead of the recent alarms.
    #[serde(default)]
    marked: bool,
    /// Only alarms of sessions on this profile.
    profile: Option<String>,
}

/// A list of alarms.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct AlarmList {
    /// The alarms.
    pub alarms: Vec<AlarmRecord>,
}

/// A session's timeline (`GET /v1/sessions/{id}/timeline`; the `timeline` event of
/// `GET /v1/live`).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct Timeline {
    /// The session.
    pub session: SessionSummary,
    /// Each detector's threshold in force, in its own units.
    pub thresholds: vamos_core::eval::DetectorThresholds,
    /// The kept points, oldest first (after frame `after` when given): an open session's
    /// last 600 frames, an ended session's whole run downsampled to at most 256 points
    /// (each the largest values of a run of frames).
    pub points: Vec<FramePoint>,
    /// The points replace what the reader has (a first answer, or the ended session's
    /// whole run once it ended) instead of following it.
    pub replace: bool,
}

/// The caller (`GET /v1/whoami`).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct Whoami {
    /// The token's role.
    pub role: Role,
    /// Whether the server checks tokens (`false`: everyone is admin).
    pub tokens: bool,
}

/// An open session with its last alarm (the `sessions` event of `GET /v1/live`).
#[derive(Debug, Clone, Serialize, schemars::JsonSchema)]
pub struct LiveSession {
    /// The session.
    pub summary: SessionSummary,
    /// Its most recent alarm.
    pub last_alarm: Option<AlarmRecord>,
}

/// The `sessions` event of `GET /v1/live`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct LiveSessions {
    /// The open sessions.
    pub sessions: Vec<LiveSession>,
}

/// A robot: its open sessions and its last ended ones.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct LiveRobot {
    /// The robot id the sessions were opened with (may be empty).
    pub robot_id: String,
    /// Its open sessions, by id.
    pub sessions: Vec<LiveSession>,
    /// Its last ended sessions (state `ended`), the latest end first; bounded by
    /// `[service] ended_sessions_per_robot` and `ended_session_max_age_s`.
    pub ended: Vec<SessionSummary>,
    /// The latest alarm of these sessions.
    pub last_alarm: Option<AlarmRecord>,
}

/// The `robots` event of `GET /v1/live`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct LiveRobots {
    /// Every robot with an open or a kept ended session the caller may see, by robot id.
    pub robots: Vec<LiveRobot>,
}

/// The `gone` event of `GET /v1/live`: the session asked for is neither open nor kept.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct LiveGone {
    /// Its id.
    pub session: String,
    /// Why (ended, or the server restarted).
    pub error: String,
}

/// One round of `GET /v1/live`: every event, or (without `Accept: text/event-stream`) the
/// one JSON snapshot.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct LiveSnapshot {
    /// The open sessions.
    pub sessions: LiveSessions,
    /// The robots, with their open and last ended sessions.
    pub robots: LiveRobots,
    /// With `?session=ID`: its new timeline points.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timeline: Option<Timeline>,
    /// With `?session=ID`: its recent alarms.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alarms: Option<AlarmList>,
    /// With `?session=ID` once it is neither open nor kept as ended.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gone: Option<LiveGone>,
}

/// `GET /v1/alarms`: the recent alarms (newest first), or with `marked=true` the stored
/// false alarms (oldest mark first), of a session / profile when given.
pub(super) async fn list_alarms(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    ApiQuery(q): ApiQuery<AlarmQuery>,
) -> Result<Response, ApiError> {
    if q.marked {
        let store = s.store.clone();
        let profile = q.profile.clone();
        let marked = tokio::task::spawn_blocking(move || store.marked_alarms(profile.as_deref()))
            .await
            .map_err(ApiError::internal)??;
        let marked: Vec<_> = marked
            .into_iter()
            .filter(|a| q.session.as_ref().is_none_or(|x| &a.session_id == x))
            .filter(|a| caller.sees(a.opener, &a.robot_id))
            .collect();
        return Ok(Json(AlarmList { alarms: marked }).into_response());
    }
    let alarms: Vec<_> = s
        .hub
        .alarms
        .list(q.session.as_deref())
        .into_iter()
        .filter(|a| q.profile.as_ref().is_none_or(|p| &a.profile == p))
        .filter(|a| caller.sees(a.opener, &a.robot_id))
        .collect();
    Ok(Json(AlarmList { alarms }).into_response())
}

/// `GET /v1/alarms/{id}`: a recent alarm, else a stored (marked) one.
pub(super) async fn get_alarm(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    Ok(Json(visible_alarm(&s, &caller, id).await?).into_response())
}

/// A recent alarm, else a stored (marked) one, if the caller may see it (else it is
/// unknown to the caller).
async fn visible_alarm(s: &Shared, caller: &Caller, id: String) -> Result<AlarmRecord, ApiError> {
    let alarm = match s.hub.alarms.get(&id).or_else(|| s.hub.history.alarm(&id)) {
        Some(a) => Some(a),
        None => {
            let store = s.store.clone();
            let key = id.clone();
            tokio::task::spawn_blocking(move || store.marked_alarm(&key))
                .await
                .map_err(ApiError::internal)??
        }
    };
    match alarm {
        Some(a) if caller.sees(a.opener, &a.robot_id) => Ok(a),
        _ => Err(SessionError::UnknownAlarm { id }.into()),
    }
}

fn png(bytes: Vec<u8>) -> Response {
    (
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        bytes,
    )
        .into_response()
}

/// `GET /v1/alarms/{id}/thumbnail`: the frame at the alarm's start (PNG, gray).
pub(super) async fn alarm_thumbnail(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let visible = s
        .hub
        .alarms
        .get(&id)
        .or_else(|| s.hub.history.alarm(&id))
        .is_some_and(|a| caller.sees(a.opener, &a.robot_id));
    match s.hub.alarms.thumbnail(&id).filter(|_| visible) {
        Some(p) => Ok(png(p)),
        None => Err(ApiError::not_found(format!(
            "no thumbnail of alarm {id:?} (unknown, older than the recent alarms, or the \
             server restarted)"
        ))),
    }
}

/// The body of a false-alarm mark (optional).
#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MarkBody {
    /// Why it is a false alarm (kept with the mark).
    #[serde(default)]
    note: String,
}

/// `POST /v1/alarms/{id}/false-alarm`: marks the alarm as a false alarm (robot or admin
/// token; a viewer's is refused before this runs) and stores it.
pub(super) async fn mark_alarm(
    State(s): State<Arc<Shared>>,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: axum::body::Bytes,
) -> Result<Response, ApiError> {
    let caller = super::authorize(&s, &headers, Role::Robot)?;
    // A robot marks only what it may see (an alarm of its own sessions).
    visible_alarm(&s, &caller, id.clone()).await?;
    let mark: MarkBody = if body.iter().all(u8::is_ascii_whitespace) {
        MarkBody::default()
    } else {
        serde_json::from_slice(&body).map_err(|e| ApiError::bad_request(format!("body: {e}")))?
    };
    let by_role = match caller.role {
        Role::Admin => "admin",
        Role::Robot => "robot",
        Role::Viewer => "viewer",
    };
    let shared = s.clone();
    let alarm = tokio::task::spawn_blocking(move || {
        mark_false_alarm(&shared.hub, &shared.store, &id, by_role, &mark.note)
    })
    .await
    .map_err(ApiError::internal)??;
    Ok(Json(alarm).into_response())
}

/// An open session the caller may see (else it is unknown to the caller).
fn open_session(
    s: &Shared,
    caller: &Caller,
    id: &str,
) -> Result<Arc<crate::session::Session>, ApiError> {
    s.hub
        .session(id)
        .filter(|x| caller.sees(x.opener, &x.robot_id))
        .ok_or_else(|| SessionError::UnknownSession { id: id.into() }.into())
}

/// An ended session the caller may see, kept by the history.
fn ended_session(s: &Shared, caller: &Caller, id: &str) -> Option<EndedSession> {
    s.hub
        .history
        .get(id)
        .filter(|e| caller.sees(e.opener, &e.robot_id))
}

/// `GET /v1/sessions/{id}/alarms`: the session's recent alarms (an ended session's
/// kept ones), newest first.
pub(super) async fn session_alarms(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    if s.hub.session(&id).is_none()
        && let Some(e) = ended_session(&s, &caller, &id)
    {
        return Ok(Json(AlarmList { alarms: e.alarms }).into_response());
    }
    let alarms: Vec<_> = s
        .hub
        .alarms
        .list(Some(&id))
        .into_iter()
        .filter(|a| caller.sees(a.opener, &a.robot_id))
        .collect();
    if alarms.is_empty() {
        // An unknown session is a 404; an open one without alarms an empty list.
        open_session(&s, &caller, &id)?;
    }
    Ok(Json(AlarmList { alarms }).into_response())
}

/// `?after=N&ended=true` of a timeline.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TimelineQuery {
    /// Only the points after this frame index (what a page already has).
    after: Option<u64>,
    /// The ended session of this id even while a session of the same id is open.
    #[serde(default)]
    ended: bool,
}

/// `GET /v1/sessions/{id}/timeline`: the kept timeline points (after frame `after`),
/// the thresholds in force and the session's summary; an open session's, else (or with
/// `ended=true`) the ended one's.
pub(super) async fn timeline(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
    ApiQuery(q): ApiQuery<TimelineQuery>,
) -> Result<Response, ApiError> {
    let open = if q.ended {
        None
    } else {
        open_session(&s, &caller, &id).ok()
    };
    if let Some(session) = open {
        let points = session.timeline(q.after);
        return Ok(Json(timeline_of(&session, points, q.after.is_none())).into_response());
    }
    match ended_session(&s, &caller, &id) {
        Some(e) => {
            let points = e
                .points
                .iter()
                .filter(|p| q.after.is_none_or(|a| p.frame > a))
                .copied()
                .collect();
            Ok(Json(ended_timeline(&e, points, q.after.is_none())).into_response())
        }
        None => Err(SessionError::UnknownSession { id }.into()),
    }
}

fn timeline_of(
    session: &crate::session::Session,
    points: Vec<FramePoint>,
    replace: bool,
) -> Timeline {
    Timeline {
        session: session.summary(),
        thresholds: session.profile().setup.detector_thresholds(),
        points,
        replace,
    }
}

fn ended_timeline(e: &EndedSession, points: Vec<FramePoint>, replace: bool) -> Timeline {
    Timeline {
        session: e.summary(),
        thresholds: e.thresholds,
        points,
        replace,
    }
}

/// The answer for the latest frame or map of a session that is not open: an ended one
/// keeps neither.
fn no_images(s: &Shared, caller: &Caller, id: &str) -> ApiError {
    if ended_session(s, caller, id).is_some() {
        ApiError::not_found(format!(
            "session {id:?} has ended: its frames are not kept (its alarms keep the frame at \
             their start)"
        ))
    } else {
        SessionError::UnknownSession { id: id.into() }.into()
    }
}

/// `GET /v1/sessions/{id}/frame`: the latest frame, shrunk (PNG, gray).
pub(super) async fn latest_frame(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let session = open_session(&s, &caller, &id).map_err(|_| no_images(&s, &caller, &id))?;
    match session.latest_images().0 {
        Some(p) => Ok(png(p)),
        None => Err(ApiError::not_found(format!(
            "session {id:?} has no scored frame yet"
        ))),
    }
}

/// `GET /v1/sessions/{id}/map`: the latest anomaly map (PNG, gray, 0 = nominal).
pub(super) async fn latest_map(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let session = open_session(&s, &caller, &id).map_err(|_| no_images(&s, &caller, &id))?;
    match session.latest_images().1 {
        Some(p) => Ok(png(p)),
        None => Err(ApiError::not_found(format!(
            "session {id:?} has no anomaly map (open it with anomaly_maps, or calibrate \
             its profile's scene residual)"
        ))),
    }
}

/// `GET /v1/whoami`: the caller's role (the page shows what it may do).
pub(super) async fn whoami(
    State(s): State<Arc<Shared>>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let caller = super::authorize(&s, &headers, Role::Viewer)?;
    Ok(Json(Whoami {
        role: caller.role,
        tokens: s.tokens.enabled(),
    })
    .into_response())
}

/// `?session=ID&ended=true` of the live stream.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LiveQuery {
    /// Also this session's timeline and alarms (or `gone`).
    session: Option<String>,
    /// The ended session of that id even while a session of the same id is open.
    #[serde(default)]
    ended: bool,
}

struct LiveState {
    shared: Arc<Shared>,
    caller: Caller,
    session: Option<String>,
    /// Only the ended session of that id.
    only_ended: bool,
    after: Option<u64>,
    /// The last round served the session as ended (its whole run was sent).
    served_ended: bool,
    stop: tokio::sync::watch::Receiver<bool>,
    first: bool,
}

/// `GET /v1/live`: with `Accept: text/event-stream`, server-sent events every half
/// second: `sessions` (the list, with each one's last alarm), `robots` (each robot's
/// open and last ended sessions), and with `?session=ID` `timeline` (new points,
/// thresholds; once the session ended, its whole run with `replace`) and `alarms`
/// (that session's), or `gone` once the session is neither open nor kept (dropped by
/// the history's bounds, or never seen); the stream ends when the server stops. Any
/// other `Accept`: one JSON snapshot of the same (`{"sessions": .., "robots": ..,
/// "timeline": .., "alarms": .., "gone": ..}`).
pub(super) async fn live(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    ApiQuery(q): ApiQuery<LiveQuery>,
    headers: HeaderMap,
) -> Response {
    let wants_stream = headers
        .get(header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.contains("text/event-stream"));
    if !wants_stream {
        let mut st = LiveState {
            stop: s.stop.subscribe(),
            shared: s,
            caller,
            session: q.session,
            only_ended: q.ended,
            after: None,
            served_ended: false,
            first: true,
        };
        return Json(live_round(&mut st)).into_response();
    }
    live_stream(s, caller, q).into_response()
}

fn live_stream(
    s: Arc<Shared>,
    caller: Caller,
    q: LiveQuery,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let state = LiveState {
        stop: s.stop.subscribe(),
        shared: s,
        caller,
        session: q.session,
        only_ended: q.ended,
        after: None,
        served_ended: false,
        first: true,
    };
    let stream = futures_util::stream::unfold(state, |mut st| async move {
        if !st.first {
            tokio::select! {
                _ = tokio::time::sleep(LIVE_PERIOD) => {}
                _ = st.stop.changed() => {}
            }
        }
        st.first = false;
        if *st.stop.borrow() {
            return None;
        }
        let events = live_events(&live_round(&mut st));
        Some((futures_util::stream::iter(events.into_iter().map(Ok)), st))
    });
    use futures_util::StreamExt;
    Sse::new(stream.flatten()).keep_alive(KeepAlive::default())
}

/// Robot `id`'s entry of `robots`, made empty when missing.
fn robot<'a>(robots: &'a mut BTreeMap<String, LiveRobot>, id: &str) -> &'a mut LiveRobot {
    robots.entry(id.to_string()).or_insert_with(|| LiveRobot {
        robot_id: id.to_string(),
        sessions: Vec::new(),
        ended: Vec::new(),
        last_alarm: None,
    })
}

/// Each robot the caller may see with its open sessions (`open`) and its kept ended
/// ones (a session that is closing shows once, open).
fn robots_of(s: &Shared, caller: &Caller, open: &[LiveSession]) -> LiveRobots {
    let mut robots: BTreeMap<String, LiveRobot> = BTreeMap::new();
    // The later start wins (ids break ties: they count up within a server's life).
    let later = |a: &Option<AlarmRecord>, b: &AlarmRecord| {
        a.as_ref()
            .is_none_or(|a| (b.started_unix_s, &b.id) > (a.started_unix_s, &a.id))
    };
    for o in open {
        let r = robot(&mut robots, &o.summary.robot_id);
        if let Some(a) = &o.last_alarm
            && later(&r.last_alarm, a)
        {
            r.last_alarm = Some(a.clone());
        }
        r.sessions.push(o.clone());
    }
    for (e, alarm) in s.hub.history.listing() {
        let closing = open
            .iter()
            .any(|o| o.summary.id == e.id && o.summary.opened_unix_s == e.opened_unix_s);
        if closing || !caller.sees(e.opener, &e.robot_id) {
            continue;
        }
        let r = robot(&mut robots, &e.robot_id);
        if let Some(a) = alarm
            && later(&r.last_alarm, &a)
        {
            r.last_alarm = Some(a);
        }
        r.ended.push(e);
    }
    LiveRobots {
        robots: robots.into_values().collect(),
    }
}

/// One round: the session list, the robots, and the session asked for.
fn live_round(st: &mut LiveState) -> LiveSnapshot {
    let s = &st.shared;
    let sessions: Vec<LiveSession> = s
        .hub
        .sessions()
        .into_iter()
        .filter(|summary| st.caller.sees(summary.opener, &summary.robot_id))
        .map(|summary| {
            let last_alarm = s.hub.alarms.list(Some(&summary.id)).into_iter().next();
            LiveSession {
                summary,
                last_alarm,
            }
        })
        .collect();
    let robots = robots_of(s, &st.caller, &sessions);
    let mut round = LiveSnapshot {
        sessions: LiveSessions { sessions },
        robots,
        timeline: None,
        alarms: None,
        gone: None,
    };
    let Some(id) = st.session.clone() else {
        return round;
    };
    let open = if st.only_ended {
        None
    } else {
        s.hub
            .session(&id)
            .filter(|x| st.caller.sees(x.opener, &x.robot_id))
    };
    if let Some(session) = open {
        if st.served_ended {
            // A session of that id opened again: its points start afresh.
            st.served_ended = false;
            st.after = None;
        }
        let replace = st.after.is_none();
        let points = session.timeline(st.after);
        if let Some(last) = points.last() {
            st.after = Some(last.frame);
        }
        round.timeline = Some(timeline_of(&session, points, replace));
        round.alarms = Some(AlarmList {
            alarms: s.hub.alarms.list(Some(&id)),
        });
    } else if let Some(e) = ended_session(s, &st.caller, &id) {
        // Its whole run once, then only its alarms (marks change them).
        let replace = !st.served_ended;
        st.served_ended = true;
        let points = if replace {
            e.points.clone()
        } else {
            Vec::new()
        };
        round.timeline = Some(ended_timeline(&e, points, replace));
        round.alarms = Some(AlarmList { alarms: e.alarms });
    } else {
        round.gone = Some(LiveGone {
            session: id.clone(),
            error: SessionError::UnknownSession { id }.to_string(),
        });
    }
    round
}

/// A round as server-sent events, in the order `sessions`, `robots`, `timeline`,
/// `alarms`, `gone`.
fn live_events(round: &LiveSnapshot) -> Vec<Event> {
    fn event<T: Serialize>(name: &str, data: Option<&T>) -> Option<Event> {
        let data = serde_json::to_string(data?).ok()?;
        Some(Event::default().event(name).data(data))
    }
    [
        event("sessions", Some(&round.sessions)),
        event("robots", Some(&round.robots)),
        event("timeline", round.timeline.as_ref()),
        event("alarms", round.alarms.as_ref()),
        event("gone", round.gone.as_ref()),
    ]
    .into_iter()
    .flatten()
    .collect()
}
