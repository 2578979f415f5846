//! Rewrites an XML VTK file into the one layout vtkio reads reliably: every binary array inline,
//! base64, uncompressed, one block of UInt64 byte count + data, and the `types` array of
//! `<Cells>` as UInt8 (vtkio takes a missing `header_type` as UInt64, where VTK's default is
//! UInt32, so files with UInt32 headers are rewritten too). What it decodes:
//!
//! - inline `format="binary"` arrays, with the header base64-encoded together with the data
//!   (VTK) or apart from it (meshio), compressed with zlib (`compressor="vtkZLibDataCompressor"`,
//!   meshio's default) or not;
//! - `format="appended"` arrays in `<AppendedData encoding="raw">` (the '<' bytes in raw data
//!   break vtkio's XML parser) or `encoding="base64"`, compressed or not;
//! - header type UInt32 or UInt64, either byte order.
//!
//! Files that need none of this are left as they are. Errors name the file, the byte offset of
//! the array's tag (or of its appended block) and the problem: truncated data, a header that
//! does not match the data, a corrupt zlib block.

use std::io::Read;
use std::path::Path;

use super::file_error as fail;
use crate::Result;

/// Integer widths of the VTK XML scalar types.
fn type_width(ty: &str) -> Option<usize> {
    Some(match ty {
        "Int8" | "UInt8" | "Char" => 1,
        "Int16" | "UInt16" => 2,
        "Int32" | "UInt32" | "Float32" => 4,
        "Int64" | "UInt64" | "Float64" => 8,
        _ => return None,
    })
}

pub(crate) fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    if needle.is_empty() || hay.len() < needle.len() {
        return None;
    }
    hay.windows(needle.len()).position(|w| w == needle)
}

/// The value of attribute `name` in a start tag (exact name, preceded by a blank).
pub(crate) fn attr<'a>(tag: &'a [u8], name: &[u8]) -> Option<&'a [u8]> {
    let mut from = 0;
    while let Some(rel) = find(&tag[from..], name) {
        let at = from + rel;
        let before_ok = at > 0 && tag[at - 1].is_ascii_whitespace();
        let mut i = at + name.len();
        while i < tag.len() && tag[i].is_ascii_whitespace() {
            i += 1;
        }
        if before_ok && i < tag.len() && tag[i] == b'=' {
            i += 1;
            while i < tag.len() && tag[i].is_ascii_whitespace() {
                i += 1;
            }
            if i < tag.len() && (tag[i] == b'"' || tag[i] == b'\'') {
                let q = tag[i];
                let s = i + 1;
                let e = tag[s..].iter().position(|&b| b == q).map(|p| s + p)?;
                return Some(&tag[s..e]);
            }
        }
        from = at + 1;
    }
    None
}

fn attr_str<'a>(tag: &'a [u8], name: &[u8]) -> Option<&'a str> {
    attr(tag, name).and_then(|v| std::str::from_utf8(v).ok())
}

/// A start tag rewritten without the attributes in `drop`, with `set` appended.
fn retag(tag: &[u8], drop: &[&[u8]], set: &[(&str, &str)]) -> Vec<u8> {
    // Split on blanks outside quotes.
    let mut parts: Vec<&[u8]> = Vec::new();
    let (mut start, mut quote) = (0usize, 0u8);
    for (i, &c) in tag.iter().enumerate() {
        if quote != 0 {
            if c == quote {
                quote = 0;
            }
        } else if c == b'"' || c == b'\'' {
            quote = c;
        } else if c.is_ascii_whitespace() {
            if i > start {
                parts.push(&tag[start..i]);
            }
            start = i + 1;
        }
    }
    if start < tag.len() {
        parts.push(&tag[start..]);
    }
    let mut out = Vec::with_capacity(tag.len() + 32);
    for (k, p) in parts.iter().enumerate() {
        let name = p.split(|&b| b == b'=').next().unwrap_or(b"");
        if k > 0 && (drop.contains(&name) || set.iter().any(|(n, _)| n.as_bytes() == name)) {
            continue;
        }
        if k > 0 {
            out.push(b' ');
        }
        out.extend_from_slice(p);
    }
    for (n, v) in set {
        out.extend_from_slice(format!(" {n}=\"{v}\"").as_bytes());
    }
    out
}

/// Standard base64 with padding.
pub(crate) fn base64(b: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(b.len().div_ceil(3) * 4);
    for c in b.chunks(3) {
        let v = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(T[(v >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// Decodes base64 text group by group (4 characters, blanks skipped), accepting padded groups
/// in the middle (a header encoded apart from its data), until `need` bytes are out or the
/// text ends. Err(offset in `text`) on a character that is not base64.
fn b64_prefix(text: &[u8], need: usize) -> std::result::Result<Vec<u8>, usize> {
    fn val(c: u8) -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return None,
        } as u32)
    }
    let mut out = Vec::with_capacity(need.min(text.len()));
    let mut group = [0u8; 4];
    let mut n = 0;
    for (i, &c) in text.iter().enumerate() {
        if out.len() >= need {
            break;
        }
        if c.is_ascii_whitespace() {
            continue;
        }
        if c != b'=' && val(c).is_none() {
            return Err(i);
        }
        group[n] = c;
        n += 1;
        if n == 4 {
            n = 0;
            let pad = group.iter().filter(|&&g| g == b'=').count();
            if pad > 2 || group[..4 - pad].contains(&b'=') {
                return Err(i);
            }
            let mut v = 0u32;
            for &g in &group {
                v = v << 6 | val(g).unwrap_or(0);
            }
            let bytes = [(v >> 16) as u8, (v >> 8) as u8, v as u8];
            out.extend_from_slice(&bytes[..3 - pad]);
        }
    }
    Ok(out)
}

/// Where an array's encoded bytes are.
enum Src<'a> {
    /// Raw bytes (appended raw): from the block start to the end of the file.
    Raw(&'a [u8]),
    /// Base64 text (inline body, or appended base64 from the block's offset on).
    B64(&'a [u8]),
}

/// Decoding context for messages and layout.
struct Ctx<'a> {
    path: &'a Path,
    /// Byte offset of the array's tag or block, for messages.
    at: usize,
    name: String,
    hsize: usize,
    big: bool,
    zlib: bool,
}

impl Ctx<'_> {
    fn err(&self, m: impl std::fmt::Display) -> crate::Error {
        fail(
            self.path,
            format!("byte {}: DataArray '{}': {m}", self.at, self.name),
        )
    }

    fn prefix(&self, src: &Src, need: usize) -> Result<Vec<u8>> {
        let got = match src {
            Src::Raw(b) => b[..need.min(b.len())].to_vec(),
            Src::B64(t) => b64_prefix(t, need).map_err(|i| {
                self.err(format!(
                    "invalid base64 data (character {} of the array's text)",
                    i + 1
                ))
            })?,
        };
        if got.len() < need {
            return Err(self.err(format!(
                "the data ends after {} of the {need} bytes its header announces: truncated \
                 file or wrong size in the header",
                got.len()
            )));
        }
        Ok(got)
    }

    fn uint(&self, b: &[u8]) -> u64 {
        let mut a = [0u8; 8];
        if self.big {
            a[8 - b.len()..].copy_from_slice(b);
            u64::from_be_bytes(a)
        } else {
            a[..b.len()].copy_from_slice(b);
            u64::from_le_bytes(a)
        }
    }

    fn header_value(&self, bytes: &[u8], k: usize) -> u64 {
        self.uint(&bytes[k * self.hsize..(k + 1) * self.hsize])
    }

    /// The decoded, decompressed bytes of one array.
    fn decode(&self, src: &Src) -> Result<Vec<u8>> {
        let h = self.hsize;
        let too_big =
            |what: &str, v: u64| self.err(format!("{what} {v} in the header is too large"));
        if !self.zlib {
            let head = self.prefix(src, h)?;
            let n = self.header_value(&head, 0);
            let n = usize::try_from(n).map_err(|_| too_big("byte count", n))?;
            let all = self.prefix(
                src,
                h.checked_add(n)
                    .ok_or_else(|| too_big("byte count", n as u64))?,
            )?;
            return Ok(all[h..].to_vec());
        }
        // zlib: [number of blocks, block size, last block size, compressed sizes...].
        let head = self.prefix(src, 3 * h)?;
        let nb = self.header_value(&head, 0);
        let bs = self.header_value(&head, 1);
        let last = self.header_value(&head, 2);
        let avail = match src {
            Src::Raw(b) => b.len(),
            Src::B64(t) => t.len(),
        } as u64;
        if nb > avail / h as u64 {
            return Err(too_big("block count", nb));
        }
        let nb = nb as usize;
        let head_len = (3 + nb) * h;
        let head = self.prefix(src, head_len)?;
        let csizes: Vec<u64> = (0..nb).map(|k| self.header_value(&head, 3 + k)).collect();
        let ctotal = csizes
            .iter()
            .try_fold(0u64, |a, &c| a.checked_add(c))
            .filter(|&t| t <= avail)
            .ok_or_else(|| self.err("the compressed block sizes in the header exceed the data"))?;
        let all = self.prefix(src, head_len + ctotal as usize)?;
        // Uncompressed sizes: bs for every block, `last` for the last one when nonzero.
        let sizes: Vec<u64> = (0..nb)
            .map(|k| if k + 1 == nb && last != 0 { last } else { bs })
            .collect();
        let total = sizes
            .iter()
            .try_fold(0u64, |a, &s| a.checked_add(s))
            .unwrap_or(u64::MAX);
        // zlib expands at most about 1032:1; anything beyond is a corrupt header.
        if total > ctotal.saturating_mul(1100).saturating_add(1 << 16) {
            return Err(self.err(format!(
                "the header announces {total} uncompressed bytes from {ctotal} compressed ones: \
                 corrupt header"
            )));
        }
        let mut out = Vec::with_capacity((total as usize).min(ctotal as usize * 8 + 4096));
        let mut pos = head_len;
        for (k, (&c, &s)) in csizes.iter().zip(&sizes).enumerate() {
            let block = &all[pos..pos + c as usize];
            pos += c as usize;
            let before = out.len();
            let mut dec = flate2::read::ZlibDecoder::new(block).take(s + 1);
            dec.read_to_end(&mut out).map_err(|e| {
                self.err(format!(
                    "zlib block {} of {nb} is corrupt ({e}): the file is damaged",
                    k + 1
                ))
            })?;
            let got = (out.len() - before) as u64;
            if got != s {
                return Err(self.err(format!(
                    "zlib block {} of {nb} decompresses to {got} bytes, the header says {s}",
                    k + 1
                )));
            }
        }
        Ok(out)
    }
}

/// The rewritten file, or None when it needs no rewriting (or is not laid out as expected: the
/// caller then lets vtkio report the problem).
pub(crate) fn normalize(bytes: &[u8], path: &Path) -> Result<Option<Vec<u8>>> {
    let Some(vf) = find(bytes, b"<VTKFile") else {
        return Ok(None);
    };
    let Some(vf_end) = bytes[vf..].iter().position(|&b| b == b'>').map(|p| vf + p) else {
        return Ok(None);
    };
    let vtag = &bytes[vf..vf_end];
    let big = attr(vtag, b"byte_order").is_some_and(|v| v == b"BigEndian");
    let hsize = if attr(vtag, b"header_type").is_some_and(|v| v == b"UInt64") {
        8
    } else {
        4
    };
    let zlib = match attr(vtag, b"compressor") {
        None => false,
        Some(b"vtkZLibDataCompressor") => true,
        // LZ4 / LZMA: vtkio decompresses those itself.
        Some(_) => return Ok(None),
    };
    // Appended data: encoding and where its bytes start (after '_').
    let app = find(bytes, b"<AppendedData");
    let appended = match app {
        Some(a) => {
            let Some(t_end) = bytes[a..].iter().position(|&b| b == b'>').map(|p| a + p) else {
                return Ok(None);
            };
            let raw = attr(&bytes[a..t_end], b"encoding").is_none_or(|e| e == b"raw");
            let Some(us) = bytes[t_end..].iter().position(|&b| b == b'_') else {
                return Err(fail(
                    path,
                    format!("byte {a}: <AppendedData> without the '_' that starts its data"),
                ));
            };
            let data = t_end + us + 1;
            let end = if raw {
                bytes.len()
            } else {
                find(&bytes[data..], b"</AppendedData>").map_or(bytes.len(), |e| data + e)
            };
            Some((raw, data, end))
        }
        None => None,
    };
    let head_end = app.unwrap_or(bytes.len());
    let head = &bytes[..head_end];

    // Ranges of <Cells> elements (their `types` array must become UInt8).
    let mut cells: Vec<(usize, usize)> = Vec::new();
    let mut from = 0;
    while let Some(r) = find(&head[from..], b"<Cells") {
        let s = from + r;
        let e = find(&head[s..], b"</Cells>").map_or(head.len(), |e| s + e);
        cells.push((s, e));
        from = e.max(s + 1);
    }

    // Does anything need rewriting? vtkio takes a missing header_type as UInt64 (VTK's
    // default is UInt32), so binary arrays with UInt32 headers are rewritten too.
    let u64_header = attr(vtag, b"header_type").is_some_and(|v| v == b"UInt64");
    let mut needed = zlib || appended.is_some();
    if !needed {
        let mut i = 0;
        while let Some(r) = find(&head[i..], b"<DataArray") {
            let s = i + r;
            let e = head[s..]
                .iter()
                .position(|&b| b == b'>')
                .map_or(head.len(), |p| s + p);
            let tag = &head[s..e];
            let in_cells = cells.iter().any(|&(a, b)| s > a && s < b);
            let binary = attr(tag, b"format") == Some(b"binary");
            if binary
                && (!u64_header
                    || (in_cells
                        && attr(tag, b"Name") == Some(b"types")
                        && attr(tag, b"type").is_some_and(|t| t != b"UInt8")))
            {
                needed = true;
                break;
            }
            i = e.max(s + 1);
        }
    }
    if !needed {
        return Ok(None);
    }

    let mut out: Vec<u8> = Vec::with_capacity(bytes.len() * 2);
    out.extend_from_slice(&bytes[..vf]);
    // Written back with UInt64 headers, stated explicitly (see above).
    out.extend_from_slice(&retag(vtag, &[b"compressor"], &[("header_type", "UInt64")]));
    let mut at = vf_end;
    while let Some(r) = find(&head[at..], b"<DataArray") {
        let s = at + r;
        let Some(e) = head[s..].iter().position(|&b| b == b'>').map(|p| s + p) else {
            return Err(fail(path, format!("byte {s}: unterminated <DataArray tag")));
        };
        out.extend_from_slice(&head[at..s]);
        at = e + 1;
        let self_closing = head[e - 1] == b'/';
        let tag = if self_closing {
            &head[s..e - 1]
        } else {
            &head[s..e]
        };
        let format = attr(tag, b"format").unwrap_or(b"ascii");
        if format != b"binary" && format != b"appended" {
            out.extend_from_slice(&head[s..=e]);
            continue;
        }
        let name = attr_str(tag, b"Name").unwrap_or("").to_string();
        let ty = attr_str(tag, b"type").unwrap_or("").to_string();
        let mut ctx = Ctx {
            path,
            at: s,
            name: if name.is_empty() {
                "(unnamed)".into()
            } else {
                name.clone()
            },
            hsize,
            big,
            zlib,
        };
        // The body of an inline array, up to its closing tag.
        let body_end = if self_closing {
            None
        } else {
            match find(&head[at..], b"</DataArray>") {
                Some(c) => Some(at + c),
                None => return Err(ctx.err("no closing </DataArray> tag: truncated file")),
            }
        };
        let data = if format == b"binary" {
            let body = &head[at..body_end.unwrap_or(at)];
            ctx.decode(&Src::B64(body))?
        } else {
            let Some((raw, start, end)) = appended else {
                return Err(ctx.err("format=\"appended\" but the file has no <AppendedData>"));
            };
            let off: usize = attr_str(tag, b"offset")
                .and_then(|o| o.trim().parse().ok())
                .ok_or_else(|| ctx.err("appended array without a valid offset"))?;
            let block = start
                .checked_add(off)
                .filter(|&b| b <= end)
                .ok_or_else(|| {
                    ctx.err(format!(
                        "offset {off} is past the end of the appended data ({} bytes)",
                        end - start
                    ))
                })?;
            ctx.at = block;
            let src = if raw {
                Src::Raw(&bytes[block..end])
            } else {
                Src::B64(&bytes[block..end])
            };
            ctx.decode(&src)?
        };
        ctx.at = s;
        if let Some(w) = type_width(&ty) {
            if data.len() % w != 0 {
                return Err(ctx.err(format!(
                    "{} bytes is not a whole number of {ty} values",
                    data.len()
                )));
            }
        }
        // `types` of <Cells> as UInt8.
        let in_cells = cells.iter().any(|&(a, b)| s > a && s < b);
        let (data, new_ty) = if in_cells && name == "types" && ty != "UInt8" {
            let w = match ty.as_str() {
                "Int8" | "Int16" | "UInt16" | "Int32" | "UInt32" | "Int64" | "UInt64" => {
                    type_width(&ty).unwrap_or(1)
                }
                _ => {
                    return Err(ctx.err(format!(
                        "cell types of type {ty}: an integer type is needed"
                    )))
                }
            };
            let mut v = Vec::with_capacity(data.len() / w);
            for (i, c) in data.chunks_exact(w).enumerate() {
                let x = ctx.uint(c);
                // Signed types: negative values have the top bit set, which is > 255 too.
                if x > 255 {
                    return Err(ctx.err(format!("cell {i} has type {x}, not a VTK cell type")));
                }
                v.push(x as u8);
            }
            (v, Some("UInt8"))
        } else {
            (data, None)
        };
        let mut block = Vec::with_capacity(8 + data.len());
        let n = data.len() as u64;
        block.extend_from_slice(&if big {
            n.to_be_bytes()
        } else {
            n.to_le_bytes()
        });
        block.extend_from_slice(&data);
        let mut set: Vec<(&str, &str)> = vec![("format", "binary")];
        if let Some(t) = new_ty {
            set.push(("type", t));
        }
        out.extend_from_slice(&retag(tag, &[b"format", b"offset"], &set));
        out.push(b'>');
        out.extend_from_slice(base64(&block).as_bytes());
        out.extend_from_slice(b"</DataArray>");
        if let Some(c) = body_end {
            at = c + b"</DataArray>".len();
        }
    }
    out.extend_from_slice(&head[at..]);
    if appended.is_some() {
        out.extend_from_slice(b"</VTKFile>\n");
    }
    Ok(Some(out))
}
