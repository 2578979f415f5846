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
    /// What the file declares for this array: (bytes, how that follows from the piece's sizes).
    declared: Option<(u64, String)>,
    /// Decompressed bytes the file's arrays may still take, of `cap` (at most [`cap`]).
    budget: u64,
    cap: u64,
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

    /// Refuses an array whose decoded size (`bytes`, from its header) is more than the file
    /// declares for it or than the memory left to the file's arrays; otherwise takes it from
    /// the budget. Run before anything is inflated or allocated.
    fn claim(&mut self, bytes: u64) -> Result<()> {
        if let Some((want, why)) = &self.declared {
            if bytes > *want {
                return Err(self.err(format!(
                    "the header announces {bytes} bytes, more than the {want} the file declares \
                     ({why}): corrupt header"
                )));
            }
        }
        if bytes > self.budget {
            return Err(self.err(format!(
                "the arrays would decompress to more than {}, the cap for one file (an \
                 eighth of the memory available, as reading takes several copies): a corrupt \
                 or hostile file, or a mesh too large for this machine",
                crate::memory::size(self.cap as f64)
            )));
        }
        self.budget -= bytes;
        Ok(())
    }

    /// The uncompressed size a compressed array's header announces, bytes, and the header:
    /// (total, header length, compressed sizes, uncompressed sizes).
    #[allow(clippy::type_complexity)]
    fn compressed_layout(&self, src: &Src) -> Result<(u64, usize, Vec<u64>, Vec<u64>)> {
        let h = self.hsize;
        let too_big =
            |what: &str, v: u64| self.err(format!("{what} {v} in the header is too large"));
        // [number of blocks, block size, last block size, compressed sizes...].
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
        // Uncompressed sizes: bs for every block, `last` for the last one when nonzero.
        let sizes: Vec<u64> = (0..nb)
            .map(|k| if k + 1 == nb && last != 0 { last } else { bs })
            .collect();
        let total = sizes
            .iter()
            .try_fold(0u64, |a, &s| a.checked_add(s))
            .unwrap_or(u64::MAX);
        Ok((total, head_len, csizes, sizes))
    }

    /// The decoded, decompressed bytes of one array.
    fn decode(&mut self, src: &Src) -> Result<Vec<u8>> {
        let h = self.hsize;
        if !self.zlib {
            let head = self.prefix(src, h)?;
            let n = self.header_value(&head, 0);
            self.claim(n)?;
            let n = usize::try_from(n)
                .map_err(|_| self.err(format!("byte count {n} in the header is too large")))?;
            let all = self.prefix(
                src,
                h.checked_add(n).ok_or_else(|| {
                    self.err(format!("byte count {n} in the header is too large"))
                })?,
            )?;
            return Ok(all[h..].to_vec());
        }
        let (total, head_len, csizes, sizes) = self.compressed_layout(src)?;
        let nb = csizes.len();
        let avail = match src {
            Src::Raw(b) => b.len(),
            Src::B64(t) => t.len(),
        } as u64;
        let ctotal = csizes
            .iter()
            .try_fold(0u64, |a, &c| a.checked_add(c))
            .filter(|&t| t <= avail)
            .ok_or_else(|| self.err("the compressed block sizes in the header exceed the data"))?;
        let all = self.prefix(src, head_len + ctotal as usize)?;
        // zlib expands at most about 1032:1; anything beyond is a corrupt header.
        if total > ctotal.saturating_mul(1100).saturating_add(1 << 16) {
            return Err(self.err(format!(
                "the header announces {total} uncompressed bytes from {ctotal} compressed ones: \
                 corrupt header"
            )));
        }
        self.claim(total)?;
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

/// Decompressed bytes one file's arrays may take: an eighth of the memory available (reading
/// holds the decoded arrays, their base64 for vtkio and vtkio's own copy), 16 GiB when the
/// available memory is unknown.
fn cap() -> u64 {
    crate::memory::available().map_or(16 << 30, |a| (a / 8.0) as u64)
}

/// The start and end tags of the file's XML part: (byte offset, the text between '<' and '>').
/// Array bodies (base64 or ASCII numbers) hold no '<', so this is one linear scan.
fn tags(head: &[u8]) -> Vec<(usize, &[u8])> {
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(r) = head[i..].iter().position(|&b| b == b'<') {
        let s = i + r;
        let Some(e) = head[s..].iter().position(|&b| b == b'>').map(|p| s + p) else {
            break;
        };
        out.push((s, &head[s + 1..e]));
        i = e + 1;
    }
    out
}

/// What the file declares for the array whose tag starts at `s`: the piece's NumberOfPoints for
/// `<Points>` and `<PointData>` arrays, NumberOfCells for `<CellData>` and the `offsets` /
/// `types` of `<Cells>`, times the components and the type's width. None where the file
/// declares no size (connectivity, field data) or the attributes are missing.
fn declared(tags: &[(usize, &[u8])], s: usize, tag: &[u8]) -> Option<(u64, String)> {
    let mut section: Option<&[u8]> = None;
    let mut piece: Option<&[u8]> = None;
    for &(_, t) in tags.iter().take_while(|(at, _)| *at < s) {
        let name_end = t
            .iter()
            .position(|&b| b.is_ascii_whitespace() || b == b'/')
            .unwrap_or(t.len());
        let closing = t.first() == Some(&b'/');
        let name = if closing { &t[1..] } else { &t[..name_end] };
        match name {
            b"Piece" if !closing => piece = Some(t),
            b"Points" | b"PointData" | b"CellData" | b"Cells" => {
                let self_closing = t.last() == Some(&b'/');
                section = (!closing && !self_closing).then_some(name);
            }
            _ => {}
        }
    }
    let piece = piece?;
    let count = |key: &[u8]| -> Option<u64> { attr_str(piece, key)?.trim().parse().ok() };
    let name = attr(tag, b"Name").unwrap_or(b"");
    let (what, tuples) = match section? {
        b"Points" | b"PointData" => ("NumberOfPoints", count(b"NumberOfPoints")?),
        b"CellData" => ("NumberOfCells", count(b"NumberOfCells")?),
        _ if name == b"offsets" || name == b"types" => ("NumberOfCells", count(b"NumberOfCells")?),
        _ => return None,
    };
    // An unreadable component count declares nothing (the parser reports it).
    let comps: u64 = match attr_str(tag, b"NumberOfComponents") {
        Some(c) => c.trim().parse().ok()?,
        None => 1,
    };
    let ty = attr_str(tag, b"type")?;
    let w = type_width(ty)? as u64;
    let bytes = tuples.checked_mul(comps)?.checked_mul(w)?;
    Some((
        bytes,
        format!("{what} {tuples} x {comps} component(s) x {w} bytes of {ty}"),
    ))
}

/// LZ4 / LZMA files, which vtkio inflates itself: every binary or appended array's header is
/// read and its uncompressed size held to what the file declares and to the cap
/// ([`Ctx::claim`]) before vtkio allocates anything.
fn check_compressed(
    bytes: &[u8],
    path: &Path,
    tags: &[(usize, &[u8])],
    appended: Option<(bool, usize, usize)>,
    hsize: usize,
    big: bool,
    budget0: u64,
) -> Result<()> {
    let mut budget = budget0;
    for (i, &(s, t)) in tags.iter().enumerate() {
        if !t.starts_with(b"DataArray") {
            continue;
        }
        let tag = t.strip_suffix(b"/").unwrap_or(t);
        let format = attr(tag, b"format").unwrap_or(b"ascii");
        let mut ctx = Ctx {
            path,
            at: s,
            name: attr_str(tag, b"Name").unwrap_or("(unnamed)").to_string(),
            hsize,
            big,
            zlib: false,
            declared: declared(tags, s, tag),
            budget,
            cap: budget0,
        };
        let total = if format == b"binary" {
            // The body runs from after the tag to the next tag.
            let from = s + t.len() + 2;
            let to = tags.get(i + 1).map_or(bytes.len(), |n| n.0).max(from);
            ctx.compressed_layout(&Src::B64(&bytes[from.min(to)..to]))?
                .0
        } else if format == b"appended" {
            let Some((raw, start, end)) = appended else {
                return Err(ctx.err("format=\"appended\" but the file has no <AppendedData>"));
            };
            let Some(block) = attr_str(tag, b"offset")
                .and_then(|o| o.trim().parse::<usize>().ok())
                .and_then(|o| start.checked_add(o))
                .filter(|&b| b <= end)
            else {
                return Err(ctx.err("appended array without a valid offset"));
            };
            ctx.at = block;
            let src = if raw {
                Src::Raw(&bytes[block..end])
            } else {
                Src::B64(&bytes[block..end])
            };
            ctx.compressed_layout(&src)?.0
        } else {
            continue;
        };
        ctx.claim(total)?;
        budget = ctx.budget;
    }
    Ok(())
}

/// The rewritten file, or None when it needs no rewriting (or is not laid out as expected: the
/// caller then lets vtkio report the problem).
pub(crate) fn normalize(bytes: &[u8], path: &Path) -> Result<Option<Vec<u8>>> {
    normalize_capped(bytes, path, cap())
}

/// Whether an inline binary array must be rewritten for vtkio although nothing is compressed
/// or appended: vtkio takes a missing header_type as UInt64 (VTK's default is UInt32), so
/// binary arrays with UInt32 headers are, and so are `types` of `<Cells>` (in `cells`, byte
/// ranges) that are not UInt8.
fn inline_needs_rewrite(head: &[u8], cells: &[(usize, usize)], u64_header: bool) -> bool {
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
            return true;
        }
        i = e.max(s + 1);
    }
    false
}

/// Cell types decoded as `ty` (an integer type) as the UInt8 values vtkio reads.
fn cell_types_u8(ctx: &Ctx, data: &[u8], ty: &str) -> Result<Vec<u8>> {
    let w = match ty {
        "Int8" | "Int16" | "UInt16" | "Int32" | "UInt32" | "Int64" | "UInt64" => {
            type_width(ty).unwrap_or(1)
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
    Ok(v)
}

/// Writes a `<DataArray>` tag (its format binary, its type `new_ty` where given) and its data
/// inline: one UInt64 byte count in the file's byte order (`big`), then the bytes, base64.
fn write_inline(out: &mut Vec<u8>, tag: &[u8], data: &[u8], new_ty: Option<&str>, big: bool) {
    let mut block = Vec::with_capacity(8 + data.len());
    let n = data.len() as u64;
    block.extend_from_slice(&if big {
        n.to_be_bytes()
    } else {
        n.to_le_bytes()
    });
    block.extend_from_slice(data);
    let mut set: Vec<(&str, &str)> = vec![("format", "binary")];
    if let Some(t) = new_ty {
        set.push(("type", t));
    }
    out.extend_from_slice(&retag(tag, &[b"format", b"offset"], &set));
    out.push(b'>');
    out.extend_from_slice(base64(&block).as_bytes());
    out.extend_from_slice(b"</DataArray>");
}

/// [`normalize`] with the arrays' decompressed bytes held to `cap`.
fn normalize_capped(bytes: &[u8], path: &Path, cap: u64) -> Result<Option<Vec<u8>>> {
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
    let (zlib, other) = match attr(vtag, b"compressor") {
        None => (false, false),
        Some(b"vtkZLibDataCompressor") => (true, false),
        // LZ4 / LZMA: vtkio decompresses those itself, after their sizes are checked.
        Some(_) => (false, true),
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
    let tag_list = tags(head);
    let mut budget = cap;
    if other {
        check_compressed(bytes, path, &tag_list, appended, hsize, big, budget)?;
        return Ok(None);
    }

    // Ranges of <Cells> elements (their `types` array must become UInt8).
    let mut cells: Vec<(usize, usize)> = Vec::new();
    let mut from = 0;
    while let Some(r) = find(&head[from..], b"<Cells") {
        let s = from + r;
        let e = find(&head[s..], b"</Cells>").map_or(head.len(), |e| s + e);
        cells.push((s, e));
        from = e.max(s + 1);
    }

    let u64_header = attr(vtag, b"header_type").is_some_and(|v| v == b"UInt64");
    if !(zlib || appended.is_some() || inline_needs_rewrite(head, &cells, u64_header)) {
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
            declared: declared(&tag_list, s, tag),
            budget,
            cap,
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
        budget = ctx.budget;
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
            (cell_types_u8(&ctx, &data, &ty)?, Some("UInt8"))
        } else {
            (data, None)
        };
        write_inline(&mut out, tag, &data, new_ty, big);
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

/// An inline (ASCII or base64) `<DataArray>` with no data, self-closing or with an empty body,
/// is an error naming its line: vtkio indexes the first data block of such an array without
/// checking that there is one. Appended arrays keep their data elsewhere.
pub(crate) fn check_empty_arrays(bytes: &[u8], path: &Path) -> Result<()> {
    let head = &bytes[..find(bytes, b"<AppendedData").unwrap_or(bytes.len())];
    let mut at = 0;
    while let Some(r) = find(&head[at..], b"<DataArray") {
        let s = at + r;
        let Some(e) = head[s..].iter().position(|&b| b == b'>').map(|p| s + p) else {
            return Err(fail(
                path,
                format!("line {}: unterminated <DataArray tag", line_of(bytes, s)),
            ));
        };
        at = e + 1;
        let tag = &head[s..e];
        if attr(tag, b"format") == Some(b"appended") {
            continue;
        }
        let empty = head[e - 1] == b'/'
            || find(&head[at..], b"</DataArray>")
                .is_some_and(|c| head[at..at + c].iter().all(u8::is_ascii_whitespace));
        if empty {
            let name = attr_str(tag, b"Name").unwrap_or("(unnamed)");
            return Err(fail(
                path,
                format!(
                    "line {}: the DataArray '{}' holds no data: the file is truncated or \
                     corrupt (write it again, e.g. with ParaView or meshio)",
                    line_of(bytes, s),
                    super::clip(name)
                ),
            ));
        }
    }
    Ok(())
}

/// Line (1-based) of byte `at`.
fn line_of(bytes: &[u8], at: usize) -> usize {
    bytes[..at.min(bytes.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// Where an XML file the parser (vtkio) rejected goes wrong, for its message, as "line L
/// (byte B): what": the first end tag that does not close the element open there, an element
/// left open at the end of the file, an integer attribute (NumberOfPoints, NumberOfCells,
/// NumberOfComponents, offset) that is not one, or else the first place the value the parser
/// names in backquotes (an unknown type name, say) appears. The parser's own
/// errors carry no position. None when none of these finds the place.
pub(crate) fn locate_parse_error(bytes: &[u8], message: &str) -> Option<String> {
    let app = find(bytes, b"<AppendedData");
    let head = &bytes[..app.unwrap_or(bytes.len())];
    let at = |b: usize| format!("line {} (byte {b})", line_of(bytes, b));
    let text = |t: &[u8]| super::clip(&String::from_utf8_lossy(t));
    let mut open: Vec<(usize, &[u8])> = Vec::new();
    for (s, t) in tags(head) {
        if t.starts_with(b"?") || t.starts_with(b"!") {
            continue;
        }
        if let Some(name) = t.strip_prefix(b"/") {
            let name = name.trim_ascii();
            match open.pop() {
                Some((_, o)) if o == name => {}
                Some((o_at, o)) => {
                    return Some(format!(
                        "{}: </{}> does not close <{}>, opened on {}",
                        at(s),
                        text(name),
                        text(o),
                        at(o_at)
                    ))
                }
                None => {
                    return Some(format!(
                        "{}: </{}> closes no open element",
                        at(s),
                        text(name)
                    ))
                }
            }
        } else if !t.ends_with(b"/") {
            let end = t
                .iter()
                .position(|b| b.is_ascii_whitespace())
                .unwrap_or(t.len());
            open.push((s, &t[..end]));
        }
    }
    if app.is_none() {
        if let Some(&(o_at, o)) = open.last() {
            return Some(format!(
                "{}: the file ends inside <{}>, opened on {}: truncated file?",
                at(bytes.len()),
                text(o),
                at(o_at)
            ));
        }
    }
    // An integer attribute that is not an integer.
    for (s, t) in tags(head) {
        for key in [
            &b"NumberOfPoints"[..],
            b"NumberOfCells",
            b"NumberOfComponents",
            b"offset",
        ] {
            if let Some(v) = attr(t, key) {
                if v.trim_ascii().is_empty() || !v.trim_ascii().iter().all(u8::is_ascii_digit) {
                    return Some(format!(
                        "{}: {}=\"{}\" is not a non-negative integer",
                        at(s),
                        text(key),
                        text(v)
                    ));
                }
            }
        }
    }
    // A value the parser names: `Float65`.
    let mut parts = message.split('`');
    parts.next();
    let value = parts.next().filter(|v| !v.is_empty())?;
    let quoted = format!("\"{value}\"");
    let b = find(head, quoted.as_bytes()).or_else(|| find(head, value.as_bytes()))?;
    Some(format!("{}: '{}'", at(b), text(value.as_bytes())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn zlib(data: &[u8]) -> Vec<u8> {
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
        e.write_all(data).unwrap();
        e.finish().unwrap()
    }

    /// A compressed one-tet VTU (UInt64 headers, one block per array) whose Points array
    /// inflates to `points_bytes` (zeros), with the piece's NumberOfPoints `npoints`.
    fn one_tet(
        compressor: &str,
        npoints: usize,
        points_bytes: usize,
        fake: Option<u64>,
    ) -> Vec<u8> {
        let array = |bytes: Vec<u8>, raw_len: u64| {
            let mut h = Vec::new();
            for v in [1u64, raw_len, raw_len, bytes.len() as u64] {
                h.extend_from_slice(&v.to_le_bytes());
            }
            base64(&h) + &base64(&bytes)
        };
        let points = match fake {
            Some(claimed) => array(vec![0u8; 16], claimed),
            None => array(zlib(&vec![0u8; points_bytes]), points_bytes as u64),
        };
        let ints = |v: &[i64]| {
            let raw: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
            array(zlib(&raw), raw.len() as u64)
        };
        format!(
            r#"<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64" compressor="{compressor}">
<UnstructuredGrid>
<Piece NumberOfPoints="{npoints}" NumberOfCells="1">
<Points>
<DataArray type="Float64" Name="Points" NumberOfComponents="3" format="binary">{points}</DataArray>
</Points>
<Cells>
<DataArray type="Int64" Name="connectivity" format="binary">{}</DataArray>
<DataArray type="Int64" Name="offsets" format="binary">{}</DataArray>
<DataArray type="UInt8" Name="types" format="binary">{}</DataArray>
</Cells>
</Piece>
</UnstructuredGrid>
</VTKFile>
"#,
            ints(&[0, 1, 2, 3]),
            ints(&[4]),
            array(zlib(&[10]), 1),
        )
        .into_bytes()
    }

    fn err(bytes: &[u8], cap: u64) -> String {
        normalize_capped(bytes, Path::new("bomb.vtu"), cap)
            .expect_err("expected an error")
            .to_string()
    }

    /// Issue 22: a zlib array that inflates to more than the piece declares (10 MB of points
    /// for 4 points: 96 bytes) is refused before anything is inflated, naming the count.
    #[test]
    fn inflated_sizes_are_held_to_what_the_file_declares() {
        let ok = one_tet("vtkZLibDataCompressor", 4, 96, None);
        assert!(normalize_capped(&ok, Path::new("ok.vtu"), 1 << 30).is_ok());
        let bomb = one_tet("vtkZLibDataCompressor", 4, 10_000_000, None);
        assert!(bomb.len() < 30_000, "{}", bomb.len());
        let e = err(&bomb, 1 << 30);
        assert!(
            e.contains("bomb.vtu: byte ")
                && e.contains("DataArray 'Points'")
                && e.contains("10000000 bytes")
                && e.contains("NumberOfPoints 4 x 3 component(s) x 8 bytes"),
            "{e}"
        );
    }

    /// Issue 22: a file consistent with itself but whose arrays would inflate past the cap (here
    /// 1 MB; an eighth of the available memory in use) is refused before inflating.
    #[test]
    fn inflated_sizes_are_held_to_the_cap() {
        let big = one_tet("vtkZLibDataCompressor", 100_000, 2_400_000, None);
        let e = err(&big, 1_000_000);
        assert!(
            e.contains("cap for one file") && e.contains("'Points'"),
            "{e}"
        );
        assert!(normalize_capped(&big, Path::new("big.vtu"), 1 << 30).is_ok());
    }

    /// LZ4 / LZMA arrays are inflated by vtkio: their headers are checked first. A header that
    /// announces 1e12 bytes for 4 points is refused without being decompressed.
    #[test]
    fn lz4_and_lzma_headers_are_checked_before_vtkio_inflates() {
        for c in ["vtkLZ4DataCompressor", "vtkLZMADataCompressor"] {
            let f = one_tet(c, 4, 0, Some(1_000_000_000_000));
            let e = err(&f, 1 << 30);
            assert!(
                e.contains("1000000000000 bytes") && e.contains("declares"),
                "{c}: {e}"
            );
            let f = one_tet(c, 4_000_000, 0, Some(96_000_000));
            let e = err(&f, 1_000_000);
            assert!(e.contains("cap for one file"), "{c}: {e}");
        }
    }
}
