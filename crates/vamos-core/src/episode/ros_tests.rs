//! ROS messages in CDR: images (step padding, 16-bit endianness, bad sizes), joint states
//! (NaN rejected), scalars and message definitions.

use super::*;

#[test]
fn image_round_trip_and_gray_with_step_padding() {
    // 2x2 bgr8 with 2 bytes of padding per row.
    let data = [
        0, 0, 255, 0, 255, 0, 9, 9, //
        255, 0, 0, 10, 20, 30, 9, 9,
    ];
    let msg = ImageMsg {
        header: Header::from_stamp_ns(1_500_000_000, "cam"),
        height: 2,
        width: 2,
        encoding: "bgr8".into(),
        is_bigendian: false,
        step: 8,
        data: &data,
    };
    let bytes = msg.encode();
    let back = ImageMsg::decode(&bytes).unwrap();
    assert_eq!(back, msg);
    assert_eq!(back.header.stamp_ns(), 1_500_000_000);
    let g = back.to_gray(1 << 20).unwrap();
    let want = [
        0.299 * 255.0,
        0.587 * 255.0,
        0.114 * 255.0,
        0.299 * 30.0 + 0.587 * 20.0 + 0.114 * 10.0,
    ];
    for (got, want) in g.data().iter().zip(want) {
        assert!((got - want).abs() < 1e-3, "{got} {want}");
    }
}

#[test]
fn sixteen_bit_honours_endianness_and_bad_sizes_are_errors() {
    let msg = ImageMsg {
        header: Header::default(),
        height: 1,
        width: 2,
        encoding: "16UC1".into(),
        is_bigendian: true,
        step: 4,
        data: &[0xff, 0xff, 0x00, 0xff],
    };
    let g = msg.to_gray(100).unwrap();
    assert_eq!(g.data()[0], 255.0);
    assert!((g.data()[1] - 255.0 * 255.0 / 65535.0).abs() < 1e-4);
    let short = ImageMsg {
        data: &[0, 0, 0],
        ..msg.clone()
    };
    assert!(matches!(
        short.to_gray(100),
        Err(MessageError::BadSize { .. })
    ));
    let narrow = ImageMsg {
        step: 3,
        ..msg.clone()
    };
    assert!(matches!(
        narrow.to_gray(100),
        Err(MessageError::BadSize { .. })
    ));
    let unknown = ImageMsg {
        encoding: "yuv422".into(),
        ..msg.clone()
    };
    assert!(matches!(
        unknown.to_gray(100),
        Err(MessageError::UnknownEncoding { .. })
    ));
    assert!(matches!(msg.to_gray(1), Err(MessageError::BadSize { .. })));
}

#[test]
fn joint_state_round_trip_and_nan_rejected() {
    let msg = JointStateMsg {
        header: Header::from_stamp_ns(-1, ""),
        name: vec!["a".into(), "b".into()],
        position: vec![0.5, -1.0],
        velocity: vec![],
        effort: vec![1.0, 2.0],
    };
    assert_eq!(msg.header.sec, -1);
    assert_eq!(msg.header.nanosec, 999_999_999);
    assert_eq!(JointStateMsg::decode(&msg.encode()).unwrap(), msg);
    let nan = JointStateMsg {
        position: vec![0.5, f64::NAN],
        ..msg.clone()
    };
    assert!(matches!(
        JointStateMsg::decode(&nan.encode()),
        Err(MessageError::NotFinite {
            field: "position",
            index: 1,
            ..
        })
    ));
    let short = JointStateMsg {
        position: vec![0.5],
        ..msg
    };
    assert!(matches!(
        JointStateMsg::decode(&short.encode()),
        Err(MessageError::BadSize { .. })
    ));
}

#[test]
fn scalars_round_trip_and_definitions_carry_dependencies() {
    assert_eq!(decode_f64(&encode_f64(2.5)).unwrap(), 2.5);
    assert!(decode_bool(&encode_bool(true)).unwrap());
    assert_eq!(decode_string(&encode_string("hi")).unwrap(), "hi");
    let image = definition(schema::IMAGE).unwrap();
    assert!(image.contains("\nMSG: std_msgs/Header\n"));
    assert!(image.contains("\nMSG: builtin_interfaces/Time\nint32 sec\n"));
    assert_eq!(definition(schema::FLOAT64).unwrap(), "float64 data\n");
    assert!(definition("foo/msg/Bar").is_none());
}
