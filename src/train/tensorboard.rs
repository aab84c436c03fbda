//! The loss curve as TensorBoard scalar events (`tensorboard --logdir runs/artifacts`), rewritten beside
//! `curve.jsonl` whenever the curve is. The file is a TFRecord stream of `Event` protocol buffers, written by
//! hand: a version event, then one event per curve point with a scalar per loss (`train/bc`, `val/bc`, ...).
//! Wall times are the step numbers, so a resumed training writes the same bytes as an uninterrupted one.
use super::curve::CurvePoint;
use anyhow::Result;
use std::path::Path;

/// The events file's name: TensorBoard reads files whose name contains `tfevents`.
pub const EVENTS_FILE: &str = "events.out.tfevents.0.oneshot-lab";

/// Writes the events of `points` to `path` atomically.
pub fn write(path: &Path, points: &[CurvePoint]) -> Result<()> {
    let with_task = points.iter().any(|p| p.task != 0.0);
    let mut out = Vec::new();
    record(&mut out, &event(0, 0.0, Payload::Version("brain.Event:2")));
    for p in points {
        let mut values = vec![("bc", p.bc), ("inverse", p.inverse), ("point", p.point), ("total", p.total)];
        if with_task {
            values.push(("task", p.task));
        }
        let values: Vec<(String, f32)> =
            values.into_iter().map(|(name, v)| (format!("{}/{name}", p.split), v as f32)).collect();
        record(&mut out, &event(p.step as i64, p.step as f64, Payload::Scalars(&values)));
    }
    crate::fsio::write_atomic(path, out)
}

/// What an event carries.
enum Payload<'a> {
    Version(&'a str),
    Scalars(&'a [(String, f32)]),
}

/// One `Event` message: wall_time (field 1, double), step (2, int64), then file_version (3, string) or summary
/// (5, `Summary { repeated Value value = 1 }`, `Value { string tag = 1; float simple_value = 2 }`).
fn event(step: i64, wall_time: f64, payload: Payload) -> Vec<u8> {
    let mut e = Vec::new();
    key(&mut e, 1, 1);
    e.extend(wall_time.to_le_bytes());
    key(&mut e, 2, 0);
    varint(&mut e, step as u64);
    match payload {
        Payload::Version(v) => bytes(&mut e, 3, v.as_bytes()),
        Payload::Scalars(values) => {
            let mut summary = Vec::new();
            for (tag, v) in values {
                let mut value = Vec::new();
                bytes(&mut value, 1, tag.as_bytes());
                key(&mut value, 2, 5);
                value.extend(v.to_le_bytes());
                bytes(&mut summary, 1, &value);
            }
            bytes(&mut e, 5, &summary);
        }
    }
    e
}

fn key(out: &mut Vec<u8>, field: u64, wire_type: u64) {
    varint(out, (field << 3) | wire_type);
}

fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// A length-delimited field.
fn bytes(out: &mut Vec<u8>, field: u64, data: &[u8]) {
    key(out, field, 2);
    varint(out, data.len() as u64);
    out.extend(data);
}

/// One TFRecord: length, its masked CRC-32C, the data, its masked CRC-32C.
fn record(out: &mut Vec<u8>, data: &[u8]) {
    let len = (data.len() as u64).to_le_bytes();
    out.extend(len);
    out.extend(masked_crc(&len).to_le_bytes());
    out.extend(data);
    out.extend(masked_crc(data).to_le_bytes());
}

/// TFRecord's masked CRC-32C.
fn masked_crc(data: &[u8]) -> u32 {
    let crc = crc32c::crc32c(data);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reads the scalars back: (step, tag, value) of every event, checking each record's checksums.
    fn read(path: &Path) -> Vec<(u64, String, f32)> {
        let data = std::fs::read(path).unwrap();
        let mut at = 0;
        let mut out = Vec::new();
        while at < data.len() {
            let len_bytes = &data[at..at + 8];
            let len = u64::from_le_bytes(len_bytes.try_into().unwrap()) as usize;
            assert_eq!(u32::from_le_bytes(data[at + 8..at + 12].try_into().unwrap()), masked_crc(len_bytes));
            let body = &data[at + 12..at + 12 + len];
            assert_eq!(u32::from_le_bytes(data[at + 12 + len..at + 16 + len].try_into().unwrap()), masked_crc(body));
            at += 16 + len;
            let fields = parse(body);
            let step = fields.iter().find(|f| f.0 == 2).map_or(0, |f| f.1);
            for (_, _, summary) in fields.iter().filter(|f| f.0 == 5) {
                for (_, _, value) in parse(summary) {
                    let v = parse(&value);
                    let tag = String::from_utf8(v.iter().find(|f| f.0 == 1).unwrap().2.clone()).unwrap();
                    let x = f32::from_le_bytes(v.iter().find(|f| f.0 == 2).unwrap().2[..4].try_into().unwrap());
                    out.push((step, tag, x));
                }
            }
        }
        out
    }

    /// Protocol-buffer fields: (number, varint value, bytes of a fixed-width or length-delimited field).
    fn parse(mut b: &[u8]) -> Vec<(u64, u64, Vec<u8>)> {
        let varint = |b: &mut &[u8]| {
            let (mut v, mut shift) = (0u64, 0);
            loop {
                let byte = b[0];
                *b = &b[1..];
                v |= u64::from(byte & 0x7f) << shift;
                shift += 7;
                if byte < 0x80 {
                    return v;
                }
            }
        };
        let mut out = Vec::new();
        while !b.is_empty() {
            let k = varint(&mut b);
            let (field, wire) = (k >> 3, k & 7);
            match wire {
                0 => out.push((field, varint(&mut b), Vec::new())),
                1 | 5 => {
                    let n = if wire == 1 { 8 } else { 4 };
                    out.push((field, 0, b[..n].to_vec()));
                    b = &b[n..];
                }
                2 => {
                    let n = varint(&mut b) as usize;
                    out.push((field, 0, b[..n].to_vec()));
                    b = &b[n..];
                }
                w => panic!("wire type {w}"),
            }
        }
        out
    }

    #[test]
    fn the_curve_round_trips_through_the_event_format() {
        let point = |step, split: &str, bc| CurvePoint {
            step,
            split: split.into(),
            bc,
            inverse: 0.5,
            point: -0.25,
            task: 0.0,
            total: bc + 0.5,
        };
        let points = [point(0, "val", 5.25), point(300, "train", 2.5), point(300, "val", 1.75)];
        let path = std::env::temp_dir().join(format!("oneshot-events-{}", std::process::id()));
        write(&path, &points).unwrap();
        let scalars = read(&path);
        assert_eq!(scalars.len(), 3 * 4, "four losses per point, no task loss without the head");
        assert!(scalars.contains(&(0, "val/bc".into(), 5.25)));
        assert!(scalars.contains(&(300, "train/total".into(), 3.0)));
        assert!(scalars.contains(&(300, "val/point".into(), -0.25)));
        // The masked CRC of TFRecord's own example: crc32c("") = 0, masked 0xa282ead8.
        assert_eq!(masked_crc(b""), 0xa282_ead8);
        std::fs::remove_file(&path).unwrap();
    }
}
