//! The ROS 2 messages vamos reads and writes, decoded from and encoded to CDR
//! ([`super::cdr`]), the `ros2msg` schema texts written into MCAP files, and the
//! conversion of image messages to [`GrayImage`] (through [`super::image`], the one
//! decoder of images, live or recorded).

use super::cdr::{CdrError, CdrReader, CdrWriter};
use super::image::EncodedImage;
use vamos_robot::{Intrinsics, IntrinsicsError};
use vamos_vision::GrayImage;

/// Schema names (`ros2msg`) of the messages vamos understands.
pub mod schema {
    /// `sensor_msgs/msg/Image`.
    pub const IMAGE: &str = "sensor_msgs/msg/Image";
    /// `sensor_msgs/msg/CompressedImage`.
    pub const COMPRESSED_IMAGE: &str = "sensor_msgs/msg/CompressedImage";
    /// `sensor_msgs/msg/CameraInfo`.
    pub const CAMERA_INFO: &str = "sensor_msgs/msg/CameraInfo";
    /// `sensor_msgs/msg/JointState`.
    pub const JOINT_STATE: &str = "sensor_msgs/msg/JointState";
    /// `std_msgs/msg/String`.
    pub const STRING: &str = "std_msgs/msg/String";
    /// `std_msgs/msg/Float64`.
    pub const FLOAT64: &str = "std_msgs/msg/Float64";
    /// `std_msgs/msg/Bool`.
    pub const BOOL: &str = "std_msgs/msg/Bool";
}

const SEP: &str =
    "================================================================================\n";

const HEADER_DEPS: &str = "================================================================================\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n\n================================================================================\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";

/// The full `ros2msg` definition text of a schema vamos writes (the message, then each
/// dependent type after a `====` line and `MSG: pkg/Type`, as rosbag2 stores them), or
/// `None` for other schemas.
pub fn definition(schema_name: &str) -> Option<String> {
    let main = match schema_name {
        schema::IMAGE => {
            "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n"
        }
        schema::COMPRESSED_IMAGE => "std_msgs/Header header\nstring format\nuint8[] data\n",
        schema::FLOAT64 => return Some("float64 data\n".into()),
        schema::BOOL => return Some("bool data\n".into()),
        schema::STRING => return Some("string data\n".into()),
        schema::JOINT_STATE => {
            "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n"
        }
        schema::CAMERA_INFO => {
            return Some(format!(
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
                 float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n\
                 uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n\n{HEADER_DEPS}\n{SEP}\
                 MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\n\
                 uint32 height\nuint32 width\nbool do_rectify\n"
            ));
        }
        _ => return None,
    };
    debug_assert!(HEADER_DEPS.starts_with(SEP));
    Some(format!("{main}\n{HEADER_DEPS}"))
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Header {
    /// Seconds of the stamp.
    pub sec: i32,
    /// Nanoseconds of the stamp.
    pub nanosec: u32,
    /// The frame id.
    pub frame_id: String,
}

impl Header {
    /// The stamp in nanoseconds.
    pub fn stamp_ns(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }

    /// A header for `stamp_ns` (floor seconds, non-negative nanoseconds).
    pub fn from_stamp_ns(stamp_ns: i64, frame_id: &str) -> Self {
        Self {
            sec: stamp_ns.div_euclid(1_000_000_000) as i32,
            nanosec: stamp_ns.rem_euclid(1_000_000_000) as u32,
            frame_id: frame_id.into(),
        }
    }

    fn read(r: &mut CdrReader<'_>) -> Result<Self, CdrError> {
        Ok(Self {
            sec: r.i32("header.stamp.sec")?,
            nanosec: r.u32("header.stamp.nanosec")?,
            frame_id: r.string("header.frame_id")?,
        })
    }

    fn write(&self, w: &mut CdrWriter) {
        w.i32(self.sec);
        w.u32(self.nanosec);
        w.string(&self.frame_id);
    }
}

/// Errors of decoding one message's content (the caller adds topic and index).
#[derive(Debug, thiserror::Error)]
pub enum MessageError {
    /// The CDR payload is malformed.
    #[error(transparent)]
    Cdr(#[from] CdrError),
    /// An image encoding vamos does not decode.
    #[error("unknown image encoding {encoding:?}")]
    UnknownEncoding {
        /// The encoding (or compressed format).
        encoding: String,
    },
    /// Sizes that do not fit together.
    #[error("{reason}")]
    BadSize {
        /// What does not fit.
        reason: String,
    },
    /// A compressed image failed to decode.
    #[error("cannot decode {format} image: {reason}")]
    Decode {
        /// The format.
        format: String,
        /// The decoder's reason.
        reason: String,
    },
    /// A value that must be finite is not.
    #[error("{field}[{index}] is {value}")]
    NotFinite {
        /// The field.
        field: &'static str,
        /// Position in the field.
        index: usize,
        /// The value.
        value: f64,
    },
    /// Camera intrinsics are invalid.
    #[error("invalid camera info: {0}")]
    Intrinsics(#[from] IntrinsicsError),
}

/// `sensor_msgs/msg/Image`, borrowing its pixel bytes from the payload.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageMsg<'a> {
    /// Header.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`rgb8`, `mono16`, ...).
    pub encoding: String,
    /// Whether multi-byte pixels are big endian.
    pub is_bigendian: bool,
    /// Bytes per row.
    pub step: u32,
    /// Pixels.
    pub data: &'a [u8],
}

/// Longest image side vamos decodes, pixels. No camera comes near it; it keeps every
/// per-axis buffer of the resize (its sampling plans) small whatever the pixel limit.
pub const MAX_IMAGE_SIDE: usize = 1 << 15;

/// Checks a declared image size (from a message or a file header, before anything is
/// decoded): not empty, no side over [`MAX_IMAGE_SIDE`], at most `max_pixels`.
pub fn check_image_size(w: usize, h: usize, max_pixels: usize) -> Result<(), MessageError> {
    let reason = if w == 0 || h == 0 {
        format!("empty image {w}x{h}")
    } else if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        format!("{w}x{h}: a side is longer than the limit of {MAX_IMAGE_SIDE} pixels")
    } else if w.saturating_mul(h) > max_pixels {
        format!("{w}x{h} exceeds the limit of {max_pixels} pixels")
    } else {
        return Ok(());
    };
    Err(MessageError::BadSize { reason })
}

impl<'a> ImageMsg<'a> {
    /// Decodes the payload.
    pub fn decode(payload: &'a [u8]) -> Result<Self, MessageError> {
        let mut r = CdrReader::new(payload)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            height: r.u32("height")?,
            width: r.u32("width")?,
            encoding: r.string("encoding")?,
            is_bigendian: r.u8("is_bigendian")? != 0,
            step: r.u32("step")?,
            data: r.bytes("data")?,
        })
    }

    /// Encodes the message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::with_capacity(self.data.len() + 64);
        self.header.write(&mut w);
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.encoding);
        w.u8(u8::from(self.is_bigendian));
        w.u32(self.step);
        w.bytes(self.data);
        w.into_bytes()
    }

    /// The message's pixels as an [`EncodedImage`].
    pub fn encoded(&self) -> EncodedImage<'_> {
        EncodedImage::raw(
            &self.encoding,
            self.width,
            self.height,
            self.step,
            self.is_bigendian,
            self.data,
        )
    }

    /// Checks encoding, sizes and `step` against the data (and `max_pixels`), without
    /// converting.
    pub fn validate(&self, max_pixels: usize) -> Result<(usize, usize), MessageError> {
        let size = self.encoded().check(max_pixels)?;
        Ok((size.width, size.height))
    }

    /// Converts to gray ([`super::image`]).
    pub fn to_gray(&self, max_pixels: usize) -> Result<GrayImage, MessageError> {
        self.encoded().to_gray(max_pixels)
    }
}

/// `sensor_msgs/msg/CompressedImage`, borrowing its bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImageMsg<'a> {
    /// Header.
    pub header: Header,
    /// Format string (contains `jpeg` or `png`).
    pub format: String,
    /// The compressed file bytes.
    pub data: &'a [u8],
}

impl<'a> CompressedImageMsg<'a> {
    /// Decodes the payload.
    pub fn decode(payload: &'a [u8]) -> Result<Self, MessageError> {
        let mut r = CdrReader::new(payload)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            format: r.string("format")?,
            data: r.bytes("data")?,
        })
    }

    /// Encodes the message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::with_capacity(self.data.len() + 64);
        self.header.write(&mut w);
        w.string(&self.format);
        w.bytes(self.data);
        w.into_bytes()
    }

    /// The file as an [`EncodedImage`] (its format named by [`Self::format`]: `jpeg`/`jpg`
    /// or `png`, any case).
    pub fn encoded(&self) -> EncodedImage<'_> {
        EncodedImage::compressed(&self.format, self.data)
    }

    /// Width and height from the file's header, nothing decoded.
    pub fn dimensions(&self) -> Result<(usize, usize), MessageError> {
        self.encoded().dimensions()
    }

    /// Decodes the image to gray ([`super::image`]). The image's declared size is checked
    /// against `max_pixels` before decoding.
    pub fn to_gray(&self, max_pixels: usize) -> Result<GrayImage, MessageError> {
        self.encoded().to_gray(max_pixels)
    }
}

/// `sensor_msgs/msg/CameraInfo` (the fields vamos uses, plus distortion for reference).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfoMsg {
    /// Header.
    pub header: Header,
    /// Image rows.
    pub height: u32,
    /// Image columns.
    pub width: u32,
    /// Distortion model name.
    pub distortion_model: String,
    /// Distortion coefficients.
    pub d: Vec<f64>,
    /// Intrinsic matrix, row-major.
    pub k: [f64; 9],
    /// Rectification rotation, row-major.
    pub r: [f64; 9],
    /// Projection matrix, row-major 3x4.
    pub p: [f64; 12],
}

impl CameraInfoMsg {
    /// Decodes the payload (binning and ROI are read and dropped).
    pub fn decode(payload: &[u8]) -> Result<Self, MessageError> {
        let mut r = CdrReader::new(payload)?;
        let header = Header::read(&mut r)?;
        let height = r.u32("height")?;
        let width = r.u32("width")?;
        let distortion_model = r.string("distortion_model")?;
        let d = r.f64_seq("d")?;
        let k = r.f64_array::<9>("k")?;
        let rm = r.f64_array::<9>("r")?;
        let p = r.f64_array::<12>("p")?;
        for field in [
            "binning_x",
            "binning_y",
            "roi.x_offset",
            "roi.y_offset",
            "roi.height",
            "roi.width",
        ] {
            r.u32(field)?;
        }
        r.bool("roi.do_rectify")?;
        Ok(Self {
            header,
            height,
            width,
            distortion_model,
            d,
            k,
            r: rm,
            p,
        })
    }

    /// A distortion-free pinhole camera info of `k` (`K` and `P` from it, `R` the
    /// identity), stamped `stamp_ns` in frame `frame_id`.
    pub fn from_intrinsics(stamp_ns: i64, frame_id: &str, k: &Intrinsics) -> Self {
        Self {
            header: Header::from_stamp_ns(stamp_ns, frame_id),
            height: k.height,
            width: k.width,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
        }
    }

    /// Encodes the message (binning 0, an empty ROI).
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::new();
        self.header.write(&mut w);
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.distortion_model);
        w.f64_seq(&self.d);
        w.f64_array(&self.k);
        w.f64_array(&self.r);
        w.f64_array(&self.p);
        for _ in 0..6 {
            w.u32(0); // binning_x, binning_y, roi.{x_offset, y_offset, height, width}
        }
        w.bool(false); // roi.do_rectify
        w.into_bytes()
    }

    /// Pinhole intrinsics from `K`, `width` and `height`.
    pub fn intrinsics(&self) -> Result<Intrinsics, MessageError> {
        Ok(Intrinsics::from_k(self.width, self.height, &self.k)?)
    }
}

/// `sensor_msgs/msg/JointState`.
#[derive(Debug, Clone, PartialEq)]
pub struct JointStateMsg {
    /// Header.
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Positions (rad or m), one per name.
    pub position: Vec<f64>,
    /// Velocities: one per name, or empty.
    pub velocity: Vec<f64>,
    /// Efforts: one per name, or empty.
    pub effort: Vec<f64>,
}

impl JointStateMsg {
    /// Decodes the payload and checks it: as many positions as names, velocities either
    /// absent or one per name, every position and velocity finite.
    pub fn decode(payload: &[u8]) -> Result<Self, MessageError> {
        let mut r = CdrReader::new(payload)?;
        let msg = Self {
            header: Header::read(&mut r)?,
            name: r.string_seq("name")?,
            position: r.f64_seq("position")?,
            velocity: r.f64_seq("velocity")?,
            effort: r.f64_seq("effort")?,
        };
        if msg.position.len() != msg.name.len() {
            return Err(MessageError::BadSize {
                reason: format!(
                    "{} positions for {} names",
                    msg.position.len(),
                    msg.name.len()
                ),
            });
        }
        if !msg.velocity.is_empty() && msg.velocity.len() != msg.name.len() {
            return Err(MessageError::BadSize {
                reason: format!(
                    "{} velocities for {} names",
                    msg.velocity.len(),
                    msg.name.len()
                ),
            });
        }
        for (field, values) in [("position", &msg.position), ("velocity", &msg.velocity)] {
            if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(MessageError::NotFinite {
                    field,
                    index,
                    value,
                });
            }
        }
        Ok(msg)
    }

    /// Encodes the message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::new();
        self.header.write(&mut w);
        w.string_seq(&self.name);
        w.f64_seq(&self.position);
        w.f64_seq(&self.velocity);
        w.f64_seq(&self.effort);
        w.into_bytes()
    }
}

/// Decodes `std_msgs/msg/String`.
pub fn decode_string(payload: &[u8]) -> Result<String, MessageError> {
    Ok(CdrReader::new(payload)?.string("data")?)
}

/// Encodes `std_msgs/msg/String`.
pub fn encode_string(s: &str) -> Vec<u8> {
    let mut w = CdrWriter::with_capacity(s.len() + 8);
    w.string(s);
    w.into_bytes()
}

/// Encodes `std_msgs/msg/Float64`.
pub fn encode_f64(v: f64) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.f64(v);
    w.into_bytes()
}

/// Decodes `std_msgs/msg/Float64`.
pub fn decode_f64(payload: &[u8]) -> Result<f64, MessageError> {
    Ok(CdrReader::new(payload)?.f64("data")?)
}

/// Encodes `std_msgs/msg/Bool`.
pub fn encode_bool(v: bool) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.bool(v);
    w.into_bytes()
}

/// Decodes `std_msgs/msg/Bool`.
pub fn decode_bool(payload: &[u8]) -> Result<bool, MessageError> {
    Ok(CdrReader::new(payload)?.bool("data")?)
}

#[cfg(test)]
#[path = "ros_tests.rs"]
mod tests;
