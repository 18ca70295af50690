//! Parsing of small text values shared by the command-line programs.

/// Parses `x,y,z` (three finite numbers).
pub fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    parse_three(s)
}

/// [`parse_vec3`] in double precision.
pub fn parse_vec3_f64(s: &str) -> Result<[f64; 3], String> {
    parse_three(s)
}

fn parse_three<T: std::str::FromStr + Copy + Into<f64>>(s: &str) -> Result<[T; 3], String> {
    let v: Vec<T> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<T>()
                .map_err(|_| format!("{x:?} in {s:?} is not a number"))
        })
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|&a| a.into().is_finite()) => Ok([x, y, z]),
        _ => Err(format!("{s:?}: expected three finite numbers x,y,z")),
    }
}
