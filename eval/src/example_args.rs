//! The command-line flags the examples (`layers`, `layer_time`, `warps`) share: the datasets'
//! folder, `--name value` lookups, `--only NAME` and the layered renderer's footprint options,
//! parsed in one place.

use std::path::Path;
use volwarp_cpu_tracer::layered::LayerOptions;
use volwarp_server::dataset::Dataset;

/// The folder of datasets an example reads when its first argument names none.
pub const DEFAULT_DATA: &str = "../shared/data";

/// The datasets of the folder the first argument names ([`DEFAULT_DATA`] where it is absent or
/// a flag), those of `--only NAME` alone; where the folder cannot be read or no name contains
/// NAME, prints why and exits with status 2.
pub fn datasets_or_exit(args: &[String]) -> Vec<Dataset> {
    let dir = folder(args).unwrap_or(DEFAULT_DATA);
    let mut datasets = match crate::report::shared_datasets(Path::new(dir)) {
        Ok(d) => d,
        Err(e) => {
            eprintln!("datasets: {e}");
            std::process::exit(2);
        }
    };
    if let Err(e) = only(args, &mut datasets, |d| &d.name) {
        eprintln!("{e}");
        std::process::exit(2);
    }
    datasets
}

/// The folder the first argument names, if it is not a flag (the examples' positional
/// arguments come first).
pub fn folder(args: &[String]) -> Option<&str> {
    args.get(1).filter(|a| !a.starts_with('-')).map(|s| s.as_str())
}

/// The value after the flag `name` in `args`, if both are there.
pub fn arg<'a>(args: &'a [String], name: &str) -> Option<&'a str> {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).map(|s| s.as_str())
}

/// `--only NAME`: keeps the `items` whose `name` contains NAME (all without the flag); where
/// none does, an error listing the names there are (not an empty run).
pub fn only<T>(args: &[String], items: &mut Vec<T>, name: impl Fn(&T) -> &str) -> Result<(), String> {
    let Some(want) = arg(args, "--only") else { return Ok(()) };
    let names: Vec<String> = items.iter().map(|i| name(i).to_string()).collect();
    items.retain(|i| name(i).contains(want));
    if items.is_empty() {
        return Err(format!("--only {want:?}: no dataset's name contains it (there are: {})", names.join(", ")));
    }
    Ok(())
}

/// The default [`LayerOptions`] with the flags `args` sets: `--own H` (half side, source
/// pixels), `--no-fill`, `--no-cracks`, `--grow G` (pixels per degree of warp; 0:
/// fixed), `--grow-from D` (degrees of warp before growing), `--grow-alpha A`, `--max-own H`, `--watertight T` (source pixels; 0: off),
/// `--water-ratio R`, `--opacity-limit F` (at most 1: a slab's opacity not scaled by its
/// footprint's area). A value that does not parse is an error naming its flag.
pub fn layer_options(args: &[String]) -> Result<LayerOptions, String> {
    fn set<T: core::str::FromStr>(args: &[String], name: &str, what: &str, v: &mut T) -> Result<(), String> {
        if let Some(s) = arg(args, name) {
            *v = s.parse().map_err(|_| format!("{name} {s:?}: not {what}"))?;
        }
        Ok(())
    }
    let flag = |name: &str| args.iter().any(|a| a == name);
    let mut o = LayerOptions::DEFAULT;
    set(args, "--own", "a distance", &mut o.own)?;
    o.fill &= !flag("--no-fill");
    o.close_cracks &= !flag("--no-cracks");
    set(args, "--grow", "a growth per degree", &mut o.grow_per_degree)?;
    set(args, "--grow-from", "an angle in degrees", &mut o.grow_from_deg)?;
    set(args, "--grow-alpha", "an 8-bit alpha", &mut o.grow_min_alpha)?;
    set(args, "--max-own", "a half side", &mut o.max_own)?;
    set(args, "--watertight", "a tolerance in source pixels", &mut o.watertight)?;
    set(args, "--water-ratio", "an area ratio", &mut o.water_ratio)?;
    set(args, "--opacity-limit", "a factor", &mut o.opacity_limit)?;
    Ok(o)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(s: &str) -> Vec<String> {
        s.split_whitespace().map(String::from).collect()
    }

    #[test]
    fn flags_set_the_footprint_options_and_bad_values_are_errors() {
        assert_eq!(layer_options(&args("prog dir")).unwrap(), LayerOptions::DEFAULT);
        let o =
            layer_options(&args("prog dir --no-cracks --watertight 0 --water-ratio 0.25 --grow 0 --opacity-limit 1"))
                .unwrap();
        assert!(!o.close_cracks && o.fill);
        assert_eq!((o.watertight, o.water_ratio, o.grow_per_degree, o.opacity_limit), (0.0, 0.25, 0.0, 1.0));
        let o = layer_options(&args("prog --no-fill --own 0.7 --grow-alpha 128 --max-own 1.5 --grow-from 2")).unwrap();
        assert_eq!((o.fill, o.own, o.grow_min_alpha, o.max_own, o.grow_from_deg), (false, 0.7, 128, 1.5, 2.0));
        let e = layer_options(&args("prog --grow-alpha 300")).unwrap_err();
        assert!(e.contains("--grow-alpha"), "{e}");
        assert!(layer_options(&args("prog --watertight x")).is_err());
        assert_eq!(arg(&args("prog --size"), "--size"), None);
    }

    #[test]
    fn only_keeps_the_names_containing_it_and_an_unknown_one_is_an_error() {
        let all = vec!["ct_head_quarter", "mri_colin27", "tooth"];
        let mut v = all.clone();
        only(&args("prog dir"), &mut v, |s| s).unwrap();
        assert_eq!(v, all);
        only(&args("prog dir --only ct_head"), &mut v, |s| s).unwrap();
        assert_eq!(v, ["ct_head_quarter"]);
        let mut v = all.clone();
        let e = only(&args("prog --only lung"), &mut v, |s| s).unwrap_err();
        assert!(e.contains("lung") && e.contains("mri_colin27"), "{e}");
    }
}
