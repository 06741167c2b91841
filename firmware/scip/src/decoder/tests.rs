//! The decoder's unit tests.

use super::line::*;
use super::*;
use crate::command::ScanMode;
use crate::response::ResponseWriter;

/// The kinds of events a whole input gives, one char each: S start, T status,
/// F field, E error, N end, other x.
fn kinds(input: &[u8]) -> String {
    let mut d = Decoder::new();
    let mut out = String::new();
    let mut rest = input;
    while !rest.is_empty() {
        let (n, ev) = d.feed(rest);
        rest = &rest[n..];
        out.push(match ev {
            None => continue,
            Some(Event::Start { .. }) => 'S',
            Some(Event::Status(_)) => 'T',
            Some(Event::Field(_)) => 'F',
            Some(Event::Error(e)) => {
                assert!(matches!(e.kind, ErrorKind::UnknownEcho(_)), "{e:?}");
                'E'
            }
            Some(Event::End(_)) => 'N',
            Some(_) => 'x',
        });
    }
    out
}

#[test]
fn an_unknown_echo_reports_its_status_before_failing() {
    // A stream frame whose echo lost a bit: status 99 reported, then the failure.
    assert_eq!(kinds(b"mD0000000101000\n99b\n0000\n000\n\n"), "STE");
    // An info answer: 00, then the failure at its first field.
    assert_eq!(kinds(b"Pp\n00P\nDMIN:20;4\n\n"), "STE");
    // Or at its end, when it has no payload line.
    assert_eq!(kinds(b"Pp\n00P\n\n"), "STE");
    // A status without payload: an answer like any other.
    assert_eq!(kinds(b"Pp\n0Ee\n\n"), "STN");
}

#[test]
fn counters_wrap_at_their_width() {
    let mut d = Decoder::new();
    d.stats = DecoderStats {
        bytes: u64::MAX,
        responses: u32::MAX,
        errors: u32::MAX,
        by_kind: [u32::MAX; ErrorKind::COUNT],
        resyncs: u32::MAX,
    };
    let feed_all = |d: &mut Decoder, mut rest: &[u8]| {
        while !rest.is_empty() {
            let (n, _) = d.feed(rest);
            rest = &rest[n..];
        }
    };
    // An intact QT answer (8 bytes), then an answer to a damaged echo (an error and
    // a resync, 8 bytes).
    feed_all(&mut d, b"QT\n00P\n\n");
    assert_eq!((d.stats.responses, d.stats.bytes), (0, 7));
    assert_eq!((d.stats.errors, d.stats.resyncs), (u32::MAX, u32::MAX));
    feed_all(&mut d, b"Pp\n00P\n\n");
    assert_eq!((d.stats.responses, d.stats.bytes), (0, 15));
    assert_eq!((d.stats.errors, d.stats.resyncs), (0, 0));
    let kind = ErrorKind::UnknownEcho(EchoError::UnknownCommand).index();
    for (i, &c) in d.stats.by_kind.iter().enumerate() {
        assert_eq!(c, if i == kind { 0 } else { u32::MAX }, "kind {i}");
    }
}

#[test]
fn distance_lines_after_intensity_lines_carry_no_old_intensity() {
    // Readings of a distance-only scan are written without their echo and aux when
    // the slots are known clear: after a scan with intensities they must be cleared.
    let (ge, _) = scan(DataSet::DistanceIntensity, 100);
    let (gd, values) = scan(DataSet::Distance, 100);
    let mut both = ge.clone();
    both.extend_from_slice(&gd);
    for chunk in [1, 7, 64, 128, 4096] {
        for make in [Decoder::new, Decoder::m4_paths] {
            let (_, after) = decode(make(), &both, chunk);
            let (_, alone) = decode(make(), &gd, chunk);
            assert_eq!(&after[100..], &alone[..], "chunk {chunk}");
            assert!(alone
                .iter()
                .zip(&values)
                .all(|(r, &(d, _))| r.distance == d && r.aux == 0 && r.echo == 0));
        }
    }
}

/// The word copy of the 32-bit data-line path against a byte-by-byte copy, check and
/// sum: every length up to past a full line, one arbitrary byte anywhere (the first,
/// the last, the overlapped last word's), lengths that differ.
#[test]
fn value_words_copied_agree_with_bytes() {
    let mut x = 0x0BAD_CAFEu32;
    let mut next = || {
        x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        x >> 8
    };
    for len in 0..=LINE_CAP + 5 {
        for round in 0..300 {
            let mut src: Vec<u8> = (0..len).map(|_| 0x30 + (next() % 0x40) as u8).collect();
            if len > 0 && round % 2 == 1 {
                let at = match round % 10 {
                    1 => 0,
                    3 => len - 1,
                    5 => len.saturating_sub(4),
                    _ => next() as usize % len,
                };
                // Edge values around the value chars, or any byte.
                src[at] = match round % 7 {
                    0 => 0x2F,
                    1 => 0x70,
                    2 => 0x30,
                    3 => 0x6F,
                    4 => b'\n',
                    _ => next() as u8,
                };
            }
            let valid = src.iter().all(|c| (0x30..=0x6F).contains(c));
            let mut dst = vec![0xAAu8; len];
            let (sum, ok) = copy_check_words(&src, &mut dst);
            assert_eq!(ok, valid, "{src:?}");
            assert_eq!(dst, src);
            if valid {
                let bytes_sum: u32 = src.iter().map(|&b| u32::from(b)).sum();
                assert_eq!(sum % 64, bytes_sum % 64, "{src:?}");
            }
        }
        // Lengths that differ: refused.
        let src = vec![b'0'; len];
        assert!(!copy_check_words(&src, &mut vec![0u8; len + 1]).1);
    }
    // Hand-computed, mod 64: "012345" is 6·48 + 15 = 303 (47); seven of the largest
    // char, 7·0x6F = 777 (9); "012" is 147 (19).
    let mut dst = [0u8; 6];
    let (sum, ok) = copy_check_words(b"012345", &mut dst);
    assert_eq!((sum % 64, ok), (47, true));
    let (sum, ok) = copy_check_words(&[0x6F; 7], &mut [0u8; 7]);
    assert_eq!((sum % 64, ok), (9, true));
    let (sum, ok) = copy_check_words(b"012", &mut [0u8; 3]);
    assert_eq!((sum % 64, ok), (19, true));
    assert!(!copy_check_words(b"01234/", &mut dst).1);
    assert!(!copy_check_words(b"p12345", &mut dst).1);
}

/// The word copy of the general line path on 32-bit targets against the library's:
/// every length up to past the line buffer's (those and unequal lengths copy nothing).
#[test]
fn line_word_copy_agrees_with_copy_from_slice() {
    for len in 0..=LINE_CAP + 5 {
        let src: Vec<u8> = (0..len).map(|i| (i * 37 + 11) as u8).collect();
        let mut dst = vec![0xAAu8; len];
        copy_line_words(&src, &mut dst);
        if len <= LINE_CAP {
            assert_eq!(dst, src, "{len} bytes");
        } else {
            assert!(dst.iter().all(|&b| b == 0xAA), "{len} bytes");
        }
        let mut longer = vec![0xAAu8; len + 1];
        copy_line_words(&src, &mut longer);
        assert!(
            longer.iter().all(|&b| b == 0xAA),
            "{len} bytes into {}",
            len + 1
        );
    }
}

/// The word copies of split data lines (64-bit hosts) against a byte-by-byte copy and
/// check: every length up to past the line buffer's, one arbitrary byte anywhere (the
/// first, a middle and the last, overlapping word alike), lengths that differ.
#[cfg(not(target_pointer_width = "32"))]
#[test]
fn word_copies_of_split_lines_agree_with_bytes() {
    let mut x = 0x5EED_1234u32;
    let mut next = || {
        x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        x >> 8
    };
    for len in 0..=LINE_CAP + 9 {
        for round in 0..200 {
            let mut src: Vec<u8> = (0..len).map(|_| 0x30 + (next() % 0x40) as u8).collect();
            if len > 0 && round % 2 == 1 {
                // One byte that may or may not be a value char, anywhere.
                let at = match round % 6 {
                    1 => 0,
                    3 => len - 1,
                    _ => next() as usize % len,
                };
                src[at] = next() as u8;
            }
            let chars = src.iter().all(|c| (0x30..=0x6F).contains(c));
            let fits = len <= LINE_CAP;

            let mut dst = vec![0xAAu8; len];
            let ok = copy_value_chars(&src, &mut dst);
            assert_eq!(ok, fits && chars, "copy_value_chars {src:?}");
            if ok {
                assert_eq!(dst, src);
            }
            let mut dst = vec![0xAAu8; len];
            let mut words = 0;
            let copied = copy_words(&src, &mut dst, |_| words += 1);
            assert_eq!(copied, fits, "copy_words, {len} bytes");
            if fits {
                assert_eq!(dst, src);
                // Every whole word, and the last eight bytes once more.
                let expected = if len < 8 { 0 } else { len / 8 + 1 };
                assert_eq!(words, expected, "{len} bytes");
            }
        }
        // Lengths that differ: refused.
        let src = vec![b'0'; len];
        let mut dst = vec![0u8; len + 1];
        assert!(!copy_value_chars(&src, &mut dst));
        assert!(!copy_words(&src, &mut dst, |_| {}));
    }
}

#[test]
fn sum_and_check_taken_while_copying_equals_the_bytewise_one() {
    // Lines of value chars (some with one arbitrary byte, never LF), their LF, in
    // pseudo-random pieces, taken as `feed` takes them in a data line on 32-bit
    // targets (the word path, else the general copy): the sum and check then
    // given for the line must be what `sum_and_check_bytes` computes over its data.
    let mut x = 0x9E37_79B9u32;
    let mut next = || {
        x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        x >> 8
    };
    for round in 0..20_000 {
        // Mostly full lines (64 data chars and the sum char), the paths' common case.
        let len = if round % 2 == 0 {
            DATA_CHARS + 1
        } else {
            1 + next() as usize % 90
        };
        let mut line: Vec<u8> = (0..len).map(|_| 0x30 + (next() % 0x40) as u8).collect();
        if next() % 2 == 0 {
            let at = next() as usize % len;
            line[at] = match next() as u8 {
                b'\n' => 0,
                b => b,
            };
        }
        let mut stream = line.clone();
        stream.push(b'\n');
        // And what follows it.
        stream.extend_from_slice(b"0\n");
        let mut d = Decoder::new();
        d.state = State::Payload(Payload::Data);
        let mut rest = &stream[..];
        let mut lf = None;
        let mut base = 0;
        while lf.is_none() && !rest.is_empty() {
            let piece = (1 + next() as usize % 70).min(rest.len());
            let taken = if d.overflow {
                None
            } else {
                d.take_data_words(&rest[..piece])
            };
            let used = match taken {
                Some((used, ends)) => {
                    if ends {
                        lf = Some(base + used - 1);
                    }
                    used
                }
                None => match d.take_line_bytes(&rest[..piece]) {
                    Some(i) => {
                        lf = Some(base + i);
                        i + 1
                    }
                    None => piece,
                },
            };
            base += used;
            rest = &rest[used..];
        }
        assert_eq!(lf, Some(len), "{line:?}");
        let expect = sum_and_check_bytes(&line[..len - 1]);
        let overflow = len > LINE_CAP;
        assert_eq!(d.overflow, overflow);
        if !overflow {
            assert_eq!(d.len, len);
            assert_eq!(&d.buf[..len], &line[..]);
            let (sum, found, valid) = d.line_sum_and_check(len).unwrap();
            assert_eq!(found, line[len - 1]);
            assert_eq!((sum, valid), expect, "{line:?}");
        }
    }
}

#[test]
fn word_sum_and_check_equals_the_bytewise_one() {
    let chars: Vec<u8> = (0x30..=0x6F).collect();
    let check = |line: &[u8]| {
        let words = sum_and_check_words(line);
        assert_eq!(words, sum_and_check_bytes(line), "{line:?}");
        words
    };
    // Every byte value at every position of short lines of value chars.
    for len in 1..=9 {
        for pos in 0..len {
            for b in 0..=255u8 {
                let mut line = chars[..len].to_vec();
                line[pos] = b;
                let (_, valid) = check(&line);
                assert_eq!(valid, (0x30..=0x6F).contains(&b));
            }
        }
    }
    // Pseudo-random lines of value chars, some with one arbitrary byte.
    let mut x = 0x1234_5678u32;
    let mut next = || {
        x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        x >> 8
    };
    for _ in 0..20_000 {
        let len = next() as usize % 200;
        let mut line: Vec<u8> = (0..len).map(|_| 0x30 + (next() % 0x40) as u8).collect();
        if len > 0 && next() % 2 == 0 {
            let at = next() as usize % len;
            line[at] = next() as u8;
        }
        check(&line);
    }
    // Long lines of the largest chars: no lane carries into the next.
    assert_eq!(check(&[0x6F; 1001]), (checksum(&[0x6F; 1001]), true));
    assert_eq!(check(&[]), (0x30, true));
}

const SETS: [DataSet; 5] = [
    DataSet::Distance,
    DataSet::ShortDistance,
    DataSet::DistanceIntensity,
    DataSet::DistanceReflectance,
    DataSet::DistanceAux,
];

/// A single-scan response over steps `0..n` of `data`, with the values written.
fn scan(data: DataSet, n: u16) -> (Vec<u8>, Vec<(u32, u32)>) {
    let request = Request::new(Command::Scan(ScanRequest {
        data,
        ..ScanRequest::distance(ScanMode::Single, 0, n - 1)
    }));
    let dmax = (1u32 << (6 * u32::from(data.distance_width()))) - 1;
    let amax = (1u64 << (6 * u32::from(data.aux_width()))) as u32 - 1;
    let values: Vec<(u32, u32)> = (0..u32::from(n))
        .map(|i| {
            let x = i.wrapping_mul(2_654_435_761);
            (x % (dmax + 1), (x >> 7) % amax.saturating_add(1))
        })
        .collect();
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    w.echo(&request);
    w.status(*b"00");
    w.timestamp(0x00AB_CDEF);
    for &(d, a) in &values {
        w.step(d, a);
    }
    w.end();
    (out, values)
}

/// Every event of `stream` fed in `chunk`-byte pieces, as text, and every reading.
fn decode(dec: Decoder, stream: &[u8], chunk: usize) -> (Vec<String>, Vec<IndexedReading>) {
    decode_pieces(dec, stream.chunks(chunk))
}

/// Every event of the stream fed to `dec` as `pieces`, as text, and every reading;
/// each call of `feed` takes bytes or gives an event.
fn decode_pieces<'a>(
    mut dec: Decoder,
    pieces: impl IntoIterator<Item = &'a [u8]>,
) -> (Vec<String>, Vec<IndexedReading>) {
    let mut log = Vec::new();
    let mut readings = Vec::new();
    for piece in pieces {
        let mut rest = piece;
        while !rest.is_empty() {
            let (used, ev) = dec.feed(rest);
            assert!(used > 0 || ev.is_some(), "no progress");
            rest = &rest[used..];
            if let Some(ev) = ev {
                if let Event::Data(line) = &ev {
                    readings.extend(line.indexed());
                }
                log.push(format!("{ev:?}"));
            }
        }
    }
    if let Some(ev) = dec.finish() {
        log.push(format!("{ev:?}"));
    }
    log.push(format!("{:?}", dec.stats()));
    (log, readings)
}

/// The fast path and the char-by-char reference agree on `stream`, whole and in
/// pieces of sizes around a line's.
fn assert_same(stream: &[u8]) -> Vec<String> {
    let whole = stream.len().max(1);
    let (reference, _) = decode(Decoder::char_by_char(), stream, whole);
    for chunk in [1, 2, 3, 5, 7, 11, 31, 63, 64, 65, 66, 67, 100, whole] {
        let (fast, _) = decode(Decoder::new(), stream, chunk);
        assert_eq!(
            fast,
            reference,
            "chunk {chunk}, stream {:?}",
            stream.escape_ascii().to_string()
        );
        let (m4, _) = decode(Decoder::m4_paths(), stream, chunk);
        assert_eq!(
            m4,
            reference,
            "m4 paths, chunk {chunk}, stream {:?}",
            stream.escape_ascii().to_string()
        );
    }
    reference
}

/// Every event of `stream` fed to `dec` in two pieces, split at `at`.
fn decode_split(dec: Decoder, stream: &[u8], at: usize) -> (Vec<String>, Vec<IndexedReading>) {
    decode_pieces(dec, [&stream[..at], &stream[at..]])
}

/// The paths of 32-bit targets (the line copy that checks and sums), with the stream
/// split in two at every byte, give the char-by-char reference's events and
/// the values the writer wrote: every data line split at each of its columns, the step
/// carried at a line's end in each phase, the last (short) line to the general rules.
#[test]
fn m4_paths_read_every_split_of_every_line() {
    for data in [DataSet::Distance, DataSet::DistanceIntensity] {
        for n in [21, 22, 23, 43, 64, 65, 66] {
            let (stream, values) = scan(data, n);
            let (reference, _) = decode(Decoder::char_by_char(), &stream, stream.len());
            assert!(reference.iter().any(|l| l.starts_with("End(")));
            for at in 0..=stream.len() {
                let (log, readings) = decode_split(Decoder::m4_paths(), &stream, at);
                assert_eq!(log, reference, "{data:?} {n}, split at {at}");
                let got: Vec<(u32, u32)> = readings.iter().map(|r| (r.distance, r.aux)).collect();
                assert_eq!(got, values, "{data:?} {n}, split at {at}");
                let indices: Vec<u16> = readings.iter().map(|r| r.index).collect();
                assert_eq!(indices, (0..n).collect::<Vec<_>>());
            }
        }
    }
}

/// Short last lines of every length after full ones on the paths of 32-bit targets: the
/// sum char of a short line (a value char like the data before it) is never taken for
/// a step.
#[test]
fn m4_paths_short_lines_of_every_length() {
    // 3 chars a step: 22 + k steps leave a last line of 2 + 3k mod 64 chars.
    for n in 1..=130 {
        let (stream, values) = scan(DataSet::Distance, n);
        let (reference, _) = decode(Decoder::char_by_char(), &stream, stream.len());
        for chunk in [1, 4, 13, 64, stream.len()] {
            let (log, readings) = decode(Decoder::m4_paths(), &stream, chunk);
            assert_eq!(log, reference, "{n} steps, chunk {chunk}");
            let got: Vec<u32> = readings.iter().map(|r| r.distance).collect();
            let want: Vec<u32> = values.iter().map(|&(d, _)| d).collect();
            assert_eq!(got, want, "{n} steps, chunk {chunk}");
        }
    }
}

/// A full data line with a wrong sum char, split at every byte: the paths of 32-bit
/// targets report the bad sum of that line as the reference does, and none of its
/// readings.
#[test]
fn m4_paths_bad_sum_at_every_split() {
    let (stream, values) = scan(DataSet::Distance, 100);
    let lfs: Vec<usize> = (0..stream.len()).filter(|&i| stream[i] == b'\n').collect();
    // The second data line (after echo, status, timestamp and the first data line).
    let line = lfs[3] + 1;
    assert_eq!(lfs[4] - line, 65);
    for wrong in [b'0', b'1', b'o', b'/', b'\n'] {
        if stream[line + 64] == wrong {
            continue;
        }
        let mut s = stream.clone();
        s[line + 64] = wrong;
        let (reference, _) = decode(Decoder::char_by_char(), &s, s.len());
        let first = reference.iter().find(|l| l.starts_with("Error(")).unwrap();
        if wrong != b'\n' {
            assert!(
                first.contains("BadSum") && first.contains(&format!("offset: {line},")),
                "{first}"
            );
        }
        for at in 0..=s.len() {
            let (log, readings) = decode_split(Decoder::m4_paths(), &s, at);
            assert_eq!(log, reference, "sum {wrong}, split at {at}");
            // Only the first line's readings (21 steps and one char of the 22nd).
            let got: Vec<u32> = readings.iter().map(|r| r.distance).collect();
            let want: Vec<u32> = values.iter().take(21).map(|&(d, _)| d).collect();
            assert_eq!(got, want, "sum {wrong}, split at {at}");
        }
    }
}

/// GE over steps 0..=10: distance 1000 + i, intensity 100 i + 7. 66 value chars: the
/// first line ends with the distance and one intensity char of step 10, whose other
/// two intensity chars open the second line (sums computed by hand).
const GE_SPLIT: &[u8] = b"GE0000001001\n00P\nZlg_<\n\
    0?X0070?Y01[0?Z03?0?[04c0?\\06G0?]07k0?^09O0?_0;30?`0<W0?a0>;0?b0a\n\
    ?_N\n\n";

#[test]
fn golden_ge_intensity_split_across_lines() {
    let mut dec = Decoder::new();
    let mut rest = GE_SPLIT;
    let mut lines = Vec::new();
    let mut end = None;
    while !rest.is_empty() {
        let (used, ev) = dec.feed(rest);
        rest = &rest[used..];
        match ev {
            Some(Event::Timestamp(t)) => assert_eq!(t, 0xAB_CDEF),
            Some(Event::Data(line)) => lines.push((line.line, line.indexed().collect::<Vec<_>>())),
            Some(Event::End(summary)) => end = Some(summary),
            Some(Event::Error(e)) => panic!("{e}"),
            _ => {}
        }
    }
    let expected = |i: u16| IndexedReading {
        index: i,
        echo: 0,
        distance: 1000 + u32::from(i),
        aux: 100 * u32::from(i) + 7,
    };
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[0], (3, (0..10).map(expected).collect::<Vec<_>>()));
    assert_eq!(lines[1], (4, vec![expected(10)]));
    let end = end.unwrap();
    assert_eq!(
        (end.values, end.lines, end.timestamp),
        (11, 5, Some(0xAB_CDEF))
    );
    assert_same(GE_SPLIT);
}

#[test]
fn golden_ge_bad_char_column_in_fast_and_reference() {
    // `p` (0x70) is one past the value chars; the sum is fixed so the decode sees it.
    let damaged = damage(GE_SPLIT, 17 + 6 + 13, Some(b'p'));
    let log = assert_same(&damaged);
    assert!(
        log.iter().any(|l| l.contains("BadChar { column: 13 }")),
        "{log:?}"
    );
}

#[test]
fn fast_path_reads_what_the_writer_wrote() {
    for data in SETS {
        for n in [1, 2, 10, 11, 21, 22, 23, 32, 33, 100, 682, 1081] {
            let (stream, values) = scan(data, n);
            let (log, readings) = decode(Decoder::new(), &stream, 64);
            assert!(
                log.iter().any(|l| l.starts_with("End(")),
                "{data:?} {n}: {log:?}"
            );
            let got: Vec<(u32, u32)> = readings.iter().map(|r| (r.distance, r.aux)).collect();
            assert_eq!(got, values, "{data:?} {n}");
            let indices: Vec<u16> = readings.iter().map(|r| r.index).collect();
            assert_eq!(indices, (0..n).collect::<Vec<_>>(), "{data:?} {n}");
            assert_same(&stream);
        }
    }
}

/// Changes byte `at` of `stream` to `c` and fixes the sum char of its line, so that
/// the damage reaches the value decoding.
fn damage(stream: &[u8], at: usize, c: Option<u8>) -> Vec<u8> {
    let mut s = stream.to_vec();
    match c {
        Some(c) => s[at] = c,
        None => {
            s.remove(at);
        }
    }
    let start = s[..at]
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    if let Some(end) = s[start..]
        .iter()
        .position(|&b| b == b'\n')
        .map(|i| start + i)
    {
        if end >= start + 2 {
            s[end - 1] = checksum(&s[start..end - 1]);
        }
    }
    s
}

/// Where the data lines of a measurement response start: after its echo, status and
/// timestamp lines.
fn first_data_byte(stream: &[u8]) -> usize {
    stream
        .iter()
        .enumerate()
        .filter(|&(_, &b)| b == b'\n')
        .nth(2)
        .map(|(i, _)| i + 1)
        .unwrap()
}

#[test]
fn fast_path_matches_char_by_char_on_damaged_values() {
    for data in SETS {
        let (stream, _) = scan(data, 40);
        let first = first_data_byte(&stream);
        for at in first..stream.len() - 2 {
            if stream[at] == b'\n' || stream.get(at + 1) == Some(&b'\n') {
                continue;
            }
            for c in [
                Some(b'/'),
                Some(b'p'),
                Some(b'&'),
                Some(b'o'),
                Some(0),
                None,
            ] {
                assert_same(&damage(&stream, at, c));
            }
        }
    }
}

#[test]
fn fast_path_counts_too_many_values_like_the_reference() {
    // The echo asks for 5 steps; the line carries 22.
    let (stream, _) = scan(DataSet::Distance, 22);
    let text = String::from_utf8(stream).unwrap();
    let damaged = text.replacen("GD0000002101", "GD0000000401", 1);
    let log = assert_same(damaged.as_bytes());
    assert!(
        log.iter()
            .any(|l| l.contains("TooManyValues { expected: 5 }")),
        "{log:?}"
    );
}

/// A frame of the stream `MD0000000101cc` (two steps, 1000 and 1001 mm), with
/// `count` scans remaining, status `status`, timestamp `ts`.
fn md_frame(count: u8, status: [u8; 2], ts: u32, values: &[u32]) -> Vec<u8> {
    let request = Request::new(Command::Scan(ScanRequest {
        count,
        ..ScanRequest::distance(ScanMode::Continuous, 0, 1)
    }));
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    w.echo(&request);
    w.status(status);
    if status != *b"00" {
        w.timestamp(ts);
        for &d in values {
            w.step(d, 0);
        }
    }
    w.end();
    out
}

/// What each response of `stream` came to: `end` or the error's name.
fn outcomes(stream: &[u8]) -> Vec<&'static str> {
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    let mut rest = stream;
    while !rest.is_empty() {
        let (used, ev) = dec.feed(rest);
        rest = &rest[used..];
        match ev {
            Some(Event::End(_)) => out.push("end"),
            Some(Event::Error(e)) => out.push(e.kind.name()),
            _ => {}
        }
    }
    out
}

#[test]
fn stream_frames_must_count_down_and_move_on_in_time() {
    let v = [1000, 1001];
    let frames: Vec<(Vec<u8>, &str)> = vec![
        (md_frame(5, *b"00", 0, &v), "end"),
        (md_frame(4, *b"99", 100, &v), "end"),
        (md_frame(3, *b"99", 200, &v), "end"),
        // The count did not go down.
        (md_frame(3, *b"99", 300, &v), "out_of_sequence"),
        // Checked against nothing after a failure.
        (md_frame(2, *b"99", 400, &v), "end"),
        // Back in time.
        (md_frame(1, *b"99", 350, &v), "out_of_sequence"),
        (md_frame(0, *b"99", 500, &v), "end"),
        // A new endless stream: its ack starts over.
        (md_frame(0, *b"00", 0, &v), "end"),
        (md_frame(0, *b"99", 0xFF_FFF0, &v), "end"),
        // The 24-bit clock wraps.
        (md_frame(0, *b"99", 0x10, &v), "end"),
        // Same time twice.
        (md_frame(0, *b"99", 0x10, &v), "out_of_sequence"),
        (md_frame(0, *b"99", 0x20, &v), "end"),
        // More than STREAM_GAP_MAX_MS on.
        (md_frame(0, *b"99", 0x20 + 10_001, &v), "out_of_sequence"),
        (md_frame(0, *b"99", 0x30 + 10_001, &v), "end"),
        // An endless stream does not count.
        (md_frame(7, *b"99", 0x40 + 10_001, &v), "out_of_sequence"),
        // A damaged frame (one value short) is no reference, and the frame after it
        // is decoded (the failure at the response's end skips nothing more).
        (
            md_frame(0, *b"99", 0x50 + 10_001, &v[..1]),
            "count_mismatch",
        ),
        (md_frame(0, *b"99", 0x60 + 10_001, &v), "end"),
    ];
    let stream: Vec<u8> = frames.iter().flat_map(|f| f.0.clone()).collect();
    let want: Vec<&str> = frames.iter().map(|f| f.1).collect();
    assert_eq!(outcomes(&stream), want);
}

#[test]
fn single_scans_and_other_streams_are_not_sequenced() {
    // A G* answer between frames, and frames of another request, are not checked
    // against the stream; a QT answer ends it.
    let v = [1000, 1001];
    let mut stream = md_frame(0, *b"99", 500, &v);
    stream.extend(b"GD0000000101\n00P\n00000\n0?X0?Y?\n\n");
    stream.extend(md_frame(0, *b"99", 600, &v));
    stream.extend(b"QT\n00P\n\n");
    stream.extend(md_frame(0, *b"99", 100, &v));
    assert_eq!(outcomes(&stream), ["end"; 5]);
}

#[test]
fn an_unknown_command_answered_without_payload_ends_intact() {
    // SCIP 2.2 RB (not a command of this crate) is answered 01, then 00.
    assert_eq!(
        outcomes(b"RB\n01Q\n\nRB\n00P\n\nXX\n00P\nabcV\n\nVV\n00P\n\n"),
        ["end", "end", "unknown_echo", "end"]
    );
}

/// Full data lines whose framing is damaged. The shortcut that takes a full line
/// without an LF search (64-bit hosts) must leave each to the line rules: the same
/// events as the char-by-char reference for every chunk size, and the error the SCIP
/// framing calls for.
#[test]
fn full_line_shortcut_leaves_damaged_framing_to_the_line_rules() {
    let (stream, _) = scan(DataSet::Distance, 100);
    let lfs: Vec<usize> = (0..stream.len()).filter(|&i| stream[i] == b'\n').collect();
    // Echo, status, timestamp, then the data lines: the second one starts after the
    // fourth LF and is full (64 data chars and the sum char).
    let line = lfs[3] + 1;
    assert_eq!(lfs[4] - line, 65);
    let fix_sum = |s: &mut Vec<u8>, start: usize| {
        let end = start + s[start..].iter().position(|&b| b == b'\n').unwrap();
        s[end - 1] = checksum(&s[start..end - 1]);
    };
    let mut wrong_sum = stream.clone();
    wrong_sum[line + 64] = if stream[line + 64] == b'0' {
        b'1'
    } else {
        b'0'
    };
    let mut long = stream.clone();
    long.insert(line + 10, b'0');
    fix_sum(&mut long, line);
    let mut joined = stream.clone();
    joined.remove(line + 65);
    let mut lf_for_sum = stream.clone();
    lf_for_sum[line + 64] = b'\n';
    let mut lf_inside = stream.clone();
    lf_inside[line + 30] = b'\n';
    let mut bad_char = stream.clone();
    bad_char[line + 7] = b'~';
    fix_sum(&mut bad_char, line);
    let cases: [(&str, Vec<u8>, Option<&str>); 6] = [
        ("wrong sum", wrong_sum, Some("BadSum")),
        ("65 data chars", long, Some("BadDataLineLength")),
        ("LF dropped", joined, Some("LineTooLong")),
        ("LF for the sum char", lf_for_sum, None),
        ("LF inside", lf_inside, None),
        ("bad char", bad_char, Some("BadChar { column: 7 }")),
    ];
    for (what, s, kind) in cases {
        let (reference, _) = decode(Decoder::char_by_char(), &s, s.len());
        assert!(
            reference.iter().any(|l| l.starts_with("Error(")),
            "{what}: no error in {reference:?}"
        );
        if let Some(kind) = kind {
            let first = reference.iter().find(|l| l.starts_with("Error(")).unwrap();
            // At the damaged line's first byte.
            assert!(
                first.contains(kind) && first.contains(&format!("offset: {line},")),
                "{what}: {first}"
            );
        }
        for chunk in (1..=140).chain([s.len()]) {
            let (fast, _) = decode(Decoder::new(), &s, chunk);
            assert_eq!(fast, reference, "{what}, chunk {chunk}");
            let (m4, _) = decode(Decoder::m4_paths(), &s, chunk);
            assert_eq!(m4, reference, "{what}, m4 paths, chunk {chunk}");
        }
    }
}

/// A multi-echo scan over steps `0..n` whose step `i` has `echoes(i)` extra echoes,
/// and every reading written, as (index, echo, distance, intensity).
fn multi_echo_scan(
    data: DataSet,
    n: u16,
    echoes: impl Fn(u16) -> u8,
) -> (Vec<u8>, Vec<IndexedReading>) {
    let request = Request::new(Command::Scan(ScanRequest {
        data,
        multi_echo: true,
        ..ScanRequest::distance(ScanMode::Single, 0, n - 1)
    }));
    let mut written = Vec::new();
    let mut out = Vec::new();
    let mut w = ResponseWriter::new(|b: &[u8]| out.extend_from_slice(b));
    w.echo(&request);
    w.status(*b"00");
    w.timestamp(0x0012_3456);
    for index in 0..n {
        for echo in 0..=echoes(index) {
            let distance = 1000 + 10 * u32::from(index) + u32::from(echo);
            let aux = if data == DataSet::Distance {
                0
            } else {
                7 * u32::from(index) + u32::from(echo)
            };
            if echo == 0 {
                w.step(distance, aux);
            } else {
                w.extra_echo(distance, aux);
            }
            written.push(IndexedReading {
                index,
                echo,
                distance,
                aux,
            });
        }
    }
    w.end();
    (out, written)
}

/// Multi-echo lines: every reading's step and echo as the writer wrote them, through
/// [`DataLine::indexed`], in any chunking; the patterns of echoes put every phase of
/// steps and `&` at the lines' ends and starts, lines that begin with an extra echo
/// among them.
#[test]
fn multi_echo_lines_give_every_reading_its_step_and_echo() {
    let mut began_with_extra = 0;
    for data in [DataSet::Distance, DataSet::DistanceIntensity] {
        for pattern in 0..6u16 {
            let echoes = move |i: u16| ((i / 3 + i * pattern) % 3) as u8;
            let (stream, written) = multi_echo_scan(data, 97, echoes);
            for chunk in [1, 7, 64, 65, 66, stream.len()] {
                for make in [Decoder::new, Decoder::m4_paths, Decoder::char_by_char] {
                    let mut dec = make();
                    let mut got = Vec::new();
                    let mut ended = false;
                    for piece in stream.chunks(chunk) {
                        let mut rest = piece;
                        while !rest.is_empty() {
                            let (used, ev) = dec.feed(rest);
                            rest = &rest[used..];
                            match ev {
                                Some(Event::Data(line)) => {
                                    assert_eq!(line.echoes.len(), line.readings.len());
                                    if line.echoes.first().is_some_and(|&e| e > 0) {
                                        began_with_extra += 1;
                                    }
                                    got.extend(line.indexed());
                                }
                                Some(Event::End(_)) => ended = true,
                                Some(Event::Error(e)) => panic!("{e}"),
                                _ => {}
                            }
                        }
                    }
                    assert!(ended);
                    assert_eq!(got, written, "{data:?} pattern {pattern} chunk {chunk}");
                }
            }
        }
    }
    assert!(began_with_extra > 0);
}

/// [`DataLine::indexed`] on lines made by hand: single-echo lines count up from
/// `first`; a multi-echo line's first reading is of step `first` whatever its echo, and
/// each later first echo begins the next step; no readings, nothing.
#[test]
fn indexed_follows_first_and_the_echo_table() {
    let r = |distance| Reading { distance, aux: 3 };
    let readings = [r(10), r(11), r(12), r(13), r(14)];
    let line = |first, echoes| DataLine {
        readings: &readings,
        first,
        echoes,
        data: DataSet::Distance,
        limits: RangeLimits::default(),
        line: 3,
    };
    let view = |l: DataLine<'_>| -> Vec<(u16, u8, u32)> {
        l.indexed().map(|x| (x.index, x.echo, x.distance)).collect()
    };
    assert_eq!(
        view(line(9998, &[])),
        [
            (9998, 0, 10),
            (9999, 0, 11),
            (10000, 0, 12),
            (10001, 0, 13),
            (10002, 0, 14)
        ]
    );
    assert_eq!(
        view(line(40, &[2, 0, 1, 0, 0])),
        [
            (40, 2, 10),
            (41, 0, 11),
            (41, 1, 12),
            (42, 0, 13),
            (43, 0, 14)
        ]
    );
    assert_eq!(
        view(line(0, &[0, 1, 2, 0, 1])),
        [(0, 0, 10), (0, 1, 11), (0, 2, 12), (1, 0, 13), (1, 1, 14)]
    );
    assert!(line(0, &[]).indexed().all(|x| x.aux == 3));
    assert_eq!(line(7, &[]).indexed().len(), 5);
    let empty = DataLine {
        readings: &[],
        ..line(7, &[])
    };
    assert_eq!(empty.indexed().count(), 0);
}

/// Every event of `stream` fed in `chunk`-byte pieces through [`Decoder::feed_runs`]
/// (`runs`) or [`Decoder::feed`], each reading of a data event as an entry of its own
/// (so that a run's entries are those of its lines), and the most readings one event
/// carried.
fn flat(mut dec: Decoder, stream: &[u8], chunk: usize, runs: bool) -> (Vec<String>, usize) {
    let mut log = Vec::new();
    let mut most = 0;
    for piece in stream.chunks(chunk.max(1)) {
        let mut rest = piece;
        while !rest.is_empty() {
            let (used, ev) = if runs {
                dec.feed_runs(rest)
            } else {
                dec.feed(rest)
            };
            assert!(used > 0 || ev.is_some(), "no progress");
            rest = &rest[used..];
            match ev {
                Some(Event::Data(line)) => {
                    most = most.max(line.readings.len());
                    log.extend(
                        line.indexed()
                            .map(|r| format!("{r:?} {:?} {:?}", line.data, line.limits)),
                    );
                }
                Some(ev) => log.push(format!("{ev:?}")),
                None => {}
            }
        }
    }
    if let Some(ev) = dec.finish() {
        log.push(format!("{ev:?}"));
    }
    log.push(format!("{:?}", dec.stats()));
    (log, most)
}

/// `feed_runs` on both paths and in pieces of many sizes gives the events and
/// readings of `feed` a byte at a time (one line per data event), every run within
/// [`MAX_RUN_READINGS`]; returns the most readings one run carried.
fn assert_runs_read_as_lines(stream: &[u8]) -> usize {
    let mut most = 0;
    let chunks = [
        1, 2, 7, 64, 65, 66, 67, 100, 128, 131, 132, 133, 197, 200, 1000,
    ];
    for make in [Decoder::new, Decoder::m4_paths] {
        let (reference, one) = flat(make(), stream, 1, false);
        assert!(one <= MAX_READINGS);
        for chunk in chunks.into_iter().chain([stream.len()]) {
            let (got, m) = flat(make(), stream, chunk, true);
            assert_eq!(
                got,
                reference,
                "chunk {chunk}, stream {:?}",
                stream.escape_ascii().to_string()
            );
            assert!(m <= MAX_RUN_READINGS, "{m} readings in one event");
            most = most.max(m);
        }
    }
    most
}

/// Runs join the full lines of 3-char distances that lie whole in one call's input
/// (three lines' readings at most), and read as the lines do; other data sets and
/// short scans read as lines too.
#[test]
fn runs_join_whole_full_lines_and_read_as_lines() {
    for n in [1, 20, 21, 22, 23, 43, 44, 64, 65, 66, 67, 100, 200, 682] {
        let (stream, values) = scan(DataSet::Distance, n);
        let most = assert_runs_read_as_lines(&stream);
        // And the readings are the values the writer wrote, at their steps.
        for make in [Decoder::new, Decoder::m4_paths] {
            for chunk in [128, stream.len()] {
                let mut dec = make();
                let mut got = Vec::new();
                for piece in stream.chunks(chunk) {
                    let mut rest = piece;
                    while !rest.is_empty() {
                        let (used, ev) = dec.feed_runs(rest);
                        rest = &rest[used..];
                        if let Some(Event::Data(line)) = ev {
                            got.extend(line.indexed().map(|r| (r.index, r.distance)));
                        }
                    }
                }
                let want: Vec<(u16, u32)> = (0..n).zip(values.iter().map(|&(d, _)| d)).collect();
                assert_eq!(got, want, "{n} steps, chunk {chunk}");
            }
        }
        // The first four full lines complete 21, 21, 22 and 21 steps (the 22nd and
        // the 43rd begun on the line before); in the largest pieces two lines join
        // (42 readings, then 43), fewer lines as many. The short last line is never
        // joined.
        let full_lines = usize::from(n) * 3 / 64;
        let want = [usize::from(n), 21, 42, 42, 43][full_lines.min(4)];
        assert!(
            most >= want,
            "{n} steps: {most} readings at most in one event"
        );
    }
    for data in SETS {
        let (stream, _) = scan(data, 100);
        assert_runs_read_as_lines(&stream);
    }
}

/// A line that fails a check is not joined: it is reported alone, at its line and
/// offset, as `feed` reports it, whatever the chunking, and no reading of it is
/// given. Damage at every char of a scan's data lines: a char that is not a value
/// char, another value char (a bad sum), an `&`, a lost byte, a stray LF.
#[test]
fn runs_leave_damaged_lines_to_be_reported_alone() {
    let (stream, _) = scan(DataSet::Distance, 120);
    let first = first_data_byte(&stream);
    for at in first..stream.len() - 2 {
        for c in [Some(b'/'), Some(b'&'), Some(b'\n'), None] {
            assert_runs_read_as_lines(&damage(&stream, at, c));
        }
        // A bad sum (the char changed, its line's sum left).
        let mut s = stream.clone();
        s[at] = if s[at] == b'0' { b'1' } else { b'0' };
        assert_runs_read_as_lines(&s);
    }
}

/// A run stops before a line that would complete more values than the echo asked
/// for: that line is reported alone as `TooManyValues`.
#[test]
fn runs_stop_before_a_line_with_too_many_values() {
    let (stream, _) = scan(DataSet::Distance, 130);
    let text = String::from_utf8(stream).unwrap();
    for asked in [22, 43, 44, 64, 65, 66, 86] {
        let echo = format!("GD{:04}{:04}01", 0, asked - 1);
        let damaged = text.replacen("GD0000012901", &echo, 1);
        assert_ne!(damaged, text);
        assert_runs_read_as_lines(damaged.as_bytes());
        let (log, _) = flat(Decoder::m4_paths(), damaged.as_bytes(), 1000, true);
        assert!(
            log.iter().any(|l| l.contains("TooManyValues")),
            "{asked}: {log:?}"
        );
    }
}

/// Stream frames back to back (each a response of its own) read as lines in runs.
#[test]
fn runs_read_stream_frames_as_lines() {
    let values: Vec<u32> = (0..300).map(|i| 20 + i * 37 % 4000).collect();
    let mut stream = Vec::new();
    for (k, count) in (90..99u8).rev().enumerate() {
        let ts = 1000 + 25 * k as u32;
        let request = Request::new(Command::Scan(ScanRequest {
            count,
            ..ScanRequest::distance(ScanMode::Continuous, 0, 299)
        }));
        let mut w = ResponseWriter::new(|b: &[u8]| stream.extend_from_slice(b));
        w.echo(&request);
        w.status(*b"99");
        w.timestamp(ts);
        for &d in &values {
            w.step(d, 0);
        }
        w.end();
    }
    assert!(assert_runs_read_as_lines(&stream) >= 42);
}
