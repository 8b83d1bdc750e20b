//! WAV files in and out: PCM (8, 16, 24, 32-bit) and 32/64-bit float, any rate, any
//! number of channels, read as mono samples in [-1, 1]; written as 16-bit mono PCM.
//! Resampling to the recogniser's rate is a windowed-sinc filter, low-passed below the
//! lower Nyquist frequency.
//!
//! A recording is input from whoever reaches the console (issue 41): every header field
//! is checked before it is used (a rate within `RATES`, at least one channel, an encoding
//! named above), chunk sizes never reach past the bytes there are, and samples are
//! finite; resampling takes any `Audio` without panicking.

use std::ops::RangeInclusive;

use std::f64::consts::PI;

/// Sample rates read, in Hz: below, no speech is left; above, no recorder writes.
pub const RATES: RangeInclusive<u32> = 1_000..=768_000;

#[derive(Debug, thiserror::Error)]
pub enum WavError {
    #[error("not a WAV file (no RIFF/WAVE header): record or convert to WAV, e.g. `ffmpeg -i in.ogg out.wav`")]
    NotWav,
    #[error("the WAV file is cut short ({0})")]
    Truncated(&'static str),
    #[error("unsupported WAV encoding (format {format}, {bits} bits): use PCM or float, e.g. `ffmpeg -i in.wav -c:a pcm_s16le out.wav`")]
    Encoding { format: u16, bits: u16 },
    #[error("the WAV file holds no samples")]
    Empty,
    #[error("the WAV file's sample rate is {0} Hz, outside {lo}–{hi} Hz: resample it, e.g. `ffmpeg -i in.wav -ar 16000 out.wav`", lo = RATES.start(), hi = RATES.end())]
    Rate(u32),
    #[error("the WAV file says it has 0 channels; record mono or stereo")]
    NoChannels,
}

/// Mono audio: samples in [-1, 1] at `rate` Hz.
#[derive(Debug, Clone)]
pub struct Audio {
    pub rate: u32,
    pub samples: Vec<f32>,
}

impl Audio {
    pub fn seconds(&self) -> f64 {
        self.samples.len() as f64 / f64::from(self.rate.max(1))
    }
}

fn u16_at(b: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([b[i], b[i + 1]])
}

fn u32_at(b: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
}

/// Read a WAV file's bytes (channels averaged to mono).
pub fn read(bytes: &[u8]) -> Result<Audio, WavError> {
    if bytes.len() < 12 || &bytes[0..4] != b"RIFF" || &bytes[8..12] != b"WAVE" {
        return Err(WavError::NotWav);
    }
    let mut at = 12;
    let mut fmt = None;
    let mut data = None;
    while at + 8 <= bytes.len() {
        let id = &bytes[at..at + 4];
        let size = u32_at(bytes, at + 4) as usize;
        let body = at + 8;
        // Within the bytes there are, whatever the size says (below `bytes.len()`).
        // A streamed WAV may say "as long as it goes" (0 or 0xFFFFFFFF) for its data.
        let end = body.saturating_add(size).min(bytes.len());
        match id {
            b"fmt " => {
                if end - body < 16 {
                    return Err(WavError::Truncated("format chunk"));
                }
                let mut format = u16_at(bytes, body);
                let channels = u16_at(bytes, body + 2);
                let rate = u32_at(bytes, body + 4);
                let bits = u16_at(bytes, body + 14);
                // WAVE_FORMAT_EXTENSIBLE: the real format is the sub-format's first two bytes.
                if format == 0xFFFE && end - body >= 26 {
                    format = u16_at(bytes, body + 24);
                }
                fmt = Some((format, channels, rate, bits));
            }
            b"data" => {
                data = Some(&bytes[body..end]);
                break;
            }
            _ => {}
        }
        at = body.saturating_add(size).saturating_add(size & 1);
    }
    let (format, channels, rate, bits) = fmt.ok_or(WavError::Truncated("no format chunk"))?;
    let data = data.ok_or(WavError::Truncated("no data chunk"))?;
    if channels == 0 {
        return Err(WavError::NoChannels);
    }
    if !RATES.contains(&rate) {
        return Err(WavError::Rate(rate));
    }
    let width = usize::from(bits / 8);
    let sample = |b: &[u8]| -> Option<f32> {
        Some(match (format, bits) {
            (1, 8) => (f32::from(b[0]) - 128.0) / 128.0,
            (1, 16) => f32::from(i16::from_le_bytes([b[0], b[1]])) / 32768.0,
            (1, 24) => (i32::from_le_bytes([0, b[0], b[1], b[2]]) >> 8) as f32 / 8_388_608.0,
            (1, 32) => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32 / 2_147_483_648.0,
            (3, 32) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            (3, 64) => f64::from_le_bytes(b[..8].try_into().ok()?) as f32,
            _ => return None,
        })
    };
    if width == 0 || sample(&[0; 8]).is_none() {
        return Err(WavError::Encoding { format, bits });
    }
    let frame = width * usize::from(channels);
    let samples: Vec<f32> = data
        .chunks_exact(frame)
        .map(|f| {
            // A float recording may hold NaN or infinities: silence, not poison.
            let sum: f32 = f
                .chunks_exact(width)
                .filter_map(sample)
                .filter(|v| v.is_finite())
                .sum();
            let v = (sum / f32::from(channels)).clamp(-1.0, 1.0);
            if v.is_finite() {
                v
            } else {
                0.0
            }
        })
        .collect();
    if samples.is_empty() {
        return Err(WavError::Empty);
    }
    Ok(Audio { rate, samples })
}

/// A 16-bit mono PCM WAV file of `audio`.
pub fn write(audio: &Audio) -> Vec<u8> {
    let data_len = audio.samples.len() * 2;
    let mut out = Vec::with_capacity(44 + data_len);
    out.extend_from_slice(b"RIFF");
    let data_len32 = u32::try_from(data_len).unwrap_or(u32::MAX);
    out.extend_from_slice(&data_len32.saturating_add(36).to_le_bytes());
    out.extend_from_slice(b"WAVEfmt ");
    out.extend_from_slice(&16u32.to_le_bytes());
    out.extend_from_slice(&1u16.to_le_bytes());
    out.extend_from_slice(&1u16.to_le_bytes());
    out.extend_from_slice(&audio.rate.to_le_bytes());
    out.extend_from_slice(&audio.rate.saturating_mul(2).to_le_bytes());
    out.extend_from_slice(&2u16.to_le_bytes());
    out.extend_from_slice(&16u16.to_le_bytes());
    out.extend_from_slice(b"data");
    out.extend_from_slice(&data_len32.to_le_bytes());
    for s in &audio.samples {
        let v = (s.clamp(-1.0, 1.0) * 32767.0).round() as i16;
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Taps on each side of the sinc filter.
const TAPS: i64 = 24;

/// `audio` at `rate` Hz (no samples when either rate is 0: there is no such audio).
pub fn resample(audio: &Audio, rate: u32) -> Audio {
    if audio.rate == rate || audio.samples.is_empty() {
        return Audio {
            rate,
            samples: audio.samples.clone(),
        };
    }
    if audio.rate == 0 || rate == 0 {
        return Audio {
            rate,
            samples: Vec::new(),
        };
    }
    let ratio = f64::from(audio.rate) / f64::from(rate);
    // Cut-off as a fraction of the source's Nyquist frequency.
    let cutoff = (1.0 / ratio).min(1.0) * 0.95;
    let n_out = (audio.samples.len() as f64 / ratio).floor() as usize;
    let x = &audio.samples;
    let samples = (0..n_out)
        .map(|n| {
            let p = n as f64 * ratio;
            let centre = p.floor() as i64;
            let mut acc = 0.0;
            for k in centre - TAPS + 1..=centre + TAPS {
                let Some(&v) = usize::try_from(k).ok().and_then(|k| x.get(k)) else {
                    continue;
                };
                let t = p - k as f64;
                let sinc = if t.abs() < 1e-9 {
                    cutoff
                } else {
                    (PI * cutoff * t).sin() / (PI * t)
                };
                // Hann window over the filter's span.
                let w = 0.5 + 0.5 * (PI * t / TAPS as f64).cos();
                acc += f64::from(v) * sinc * w;
            }
            acc as f32
        })
        .collect();
    Audio { rate, samples }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tone(rate: u32, hz: f64, secs: f64) -> Audio {
        let n = (f64::from(rate) * secs) as usize;
        Audio {
            rate,
            samples: (0..n)
                .map(|i| (0.5 * (2.0 * PI * hz * i as f64 / f64::from(rate)).sin()) as f32)
                .collect(),
        }
    }

    #[test]
    fn round_trips_and_reads_the_encodings_it_names() {
        let a = tone(22050, 440.0, 0.1);
        let b = read(&write(&a)).unwrap();
        assert_eq!(b.rate, 22050);
        assert_eq!(b.samples.len(), a.samples.len());
        assert!(a
            .samples
            .iter()
            .zip(&b.samples)
            .all(|(x, y)| (x - y).abs() < 1e-4));
        // Stereo float: averaged.
        let mut f = write(&Audio {
            rate: 8000,
            samples: vec![0.0; 2],
        });
        f[22] = 2; // channels
        f[34] = 32; // bits
        f[20] = 3; // float
        let body: Vec<u8> = [0.5f32, -0.5, 1.0, 0.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        f.truncate(44);
        f[40..44].copy_from_slice(&(body.len() as u32).to_le_bytes());
        f.extend_from_slice(&body);
        assert_eq!(read(&f).unwrap().samples, vec![0.0, 0.5]);
        assert!(matches!(read(b"OggS...."), Err(WavError::NotWav)));
        let mut odd = write(&a);
        odd[34] = 12;
        assert!(matches!(
            read(&odd),
            Err(WavError::Encoding { bits: 12, .. })
        ));
    }

    #[test]
    fn crafted_headers_are_refused_with_the_field_they_got_wrong() {
        let good = write(&tone(16000, 440.0, 0.01));
        let with = |at: usize, v: &[u8]| {
            let mut b = good.clone();
            b[at..at + v.len()].copy_from_slice(v);
            read(&b)
        };
        assert!(matches!(
            with(24, &0u32.to_le_bytes()),
            Err(WavError::Rate(0))
        ));
        assert!(matches!(
            with(24, &u32::MAX.to_le_bytes()),
            Err(WavError::Rate(u32::MAX))
        ));
        assert!(matches!(with(22, &[0, 0]), Err(WavError::NoChannels)));
        assert!(matches!(
            with(34, &[0, 0]),
            Err(WavError::Encoding { bits: 0, .. })
        ));
        // A data chunk claiming 4 GiB: what is there is read.
        let b = with(40, &u32::MAX.to_le_bytes()).unwrap();
        assert_eq!(b.samples.len(), 160);
        // Float NaN and infinity are silence.
        let mut f = write(&Audio {
            rate: 8000,
            samples: vec![0.0; 2],
        });
        f[20] = 3;
        f[34] = 32;
        f.truncate(44);
        f[40..44].copy_from_slice(&8u32.to_le_bytes());
        f.extend_from_slice(&f32::NAN.to_le_bytes());
        f.extend_from_slice(&f32::INFINITY.to_le_bytes());
        assert_eq!(read(&f).unwrap().samples, vec![0.0, 0.0]);
        // Resampling takes any audio.
        let zero = Audio {
            rate: 0,
            samples: vec![0.5; 10],
        };
        assert!(resample(&zero, 16000).samples.is_empty());
        assert!(resample(&tone(16000, 440.0, 0.01), 0).samples.is_empty());
    }

    #[test]
    fn resampling_keeps_a_tone_and_removes_what_the_new_rate_cannot_hold() {
        let a = resample(&tone(22050, 440.0, 0.5), 16000);
        assert_eq!(a.rate, 16000);
        assert!((a.samples.len() as i64 - 8000).abs() <= 1);
        let expect = tone(16000, 440.0, 0.5);
        let mid = 1000..7000;
        let err = a.samples[mid.clone()]
            .iter()
            .zip(&expect.samples[mid.clone()])
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max);
        assert!(err < 0.02, "{err}");
        // 10 kHz is above 16 kHz's Nyquist frequency: nearly nothing is left.
        let high = resample(&tone(44100, 10_000.0, 0.5), 16000);
        let peak = high.samples[mid]
            .iter()
            .map(|v| v.abs())
            .fold(0f32, f32::max);
        assert!(peak < 0.05, "{peak}");
    }
}
