//! Numbers on data lines: ids and coordinates.

/// A positive integer id; the message quotes the field.
pub(super) fn parse_id(s: &str, what: &str) -> std::result::Result<u64, String> {
    if s.is_empty() {
        return Err(format!("empty {what} field"));
    }
    match s.parse::<u64>() {
        Ok(0) => Err(format!("{what} '0' (ids must be positive)")),
        Ok(v) => Ok(v),
        Err(_) => {
            if s.parse::<f64>().is_ok() {
                Err(format!("{what} '{s}' is not a positive integer"))
            } else {
                Err(format!("non-numeric {what} '{s}'"))
            }
        }
    }
}

/// A finite coordinate; blank is 0; Fortran `D` exponents accepted.
pub(super) fn parse_coord(s: &str) -> std::result::Result<f64, String> {
    if s.is_empty() {
        return Ok(0.0);
    }
    let v = if s.contains(['d', 'D']) {
        s.replace(['d', 'D'], "e").parse::<f64>()
    } else {
        s.parse::<f64>()
    };
    match v {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("non-finite coordinate '{s}'")),
        Err(_) => Err(format!("non-numeric coordinate '{s}'")),
    }
}
