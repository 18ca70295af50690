//! Parsing of small text values shared by the command-line programs.

/// Parses `x,y,z`.
pub fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<f32>()
                .map_err(|_| format!("{x:?} in {s:?} is not a number"))
        })
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|a| a.is_finite()) => Ok([x, y, z]),
        _ => Err(format!("{s:?}: expected three finite numbers x,y,z")),
    }
}
