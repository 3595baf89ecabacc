//! The `matedit` command line's parsing: ranges refused by name, defaults, and what each
//! command passes on.

use super::*;

fn parse(args: &[&str]) -> Result<Cli, clap::Error> {
    let base = [
        "matedit",
        "edit",
        "--model",
        "m",
        "--image",
        "p.png",
        "--material",
        "lambert:0.5,0.5,0.5",
        "--out",
        "o",
    ];
    Cli::try_parse_from(base.iter().chain(args))
}

#[test]
fn eq6_settings_outside_their_ranges_are_refused_naming_the_option() {
    for (option, value) in [
        ("--eq6-a", "NaN"),
        ("--eq6-a", "inf"),
        ("--eq6-a", "-5"),
        ("--eq6-b", "-1"),
        ("--eq6-b", "1e300"),
        ("--eq6-b", "x"),
        ("--eq6-rounds", "0"),
        ("--eq6-rounds", "101"),
        ("--eq6-iterations", "0"),
        ("--eq6-iterations", "-1"),
        ("--fov", "0"),
        ("--fov", "NaN"),
        ("--fov", "171"),
        ("--fov", "-40"),
        ("--light-level", "sky"),
        ("--relight-level", "sky"),
        // Without --relight it would set nothing.
        ("--relight-level", "given"),
    ] {
        let e = parse(&[option, value])
            .err()
            .unwrap_or_else(|| panic!("{option} {value} accepted"));
        let text = e.to_string();
        assert!(text.contains(option), "{option} {value}: {text}");
    }
    for (option, value) in [
        ("--eq6-a", "0"),
        ("--eq6-b", "1e6"),
        ("--eq6-rounds", "100"),
        ("--eq6-iterations", "1"),
        ("--fov", "1"),
        ("--fov", "170"),
        ("--light-level", "network"),
    ] {
        assert!(parse(&[option, value]).is_ok(), "{option} {value} refused");
    }
    // No --composite leaves the choice to what is known: `ratio` with the material, `detail`
    // with a light at a known level, `structure` with neither.
    let composite = |args: &[&str]| match parse(args).map(|c| c.command) {
        Ok(Command::Edit(EditArgs { composite, .. })) => composite,
        _ => panic!("{args:?} refused"),
    };
    assert_eq!(composite(&["--input-material", "library:red-plastic"]), None);
    assert_eq!(composite(&["--composite", "render"]), Some(Composite::Render));
    let relight_level = |args: &[&str]| match parse(args).map(|c| c.command) {
        Ok(Command::Edit(EditArgs { relight_level, .. })) => relight_level,
        _ => panic!("{args:?} refused"),
    };
    assert_eq!(relight_level(&["--relight", "builtin:sky"]), RelightLevel::Light);
    assert_eq!(
        relight_level(&["--relight", "builtin:sky", "--relight-level", "given"]),
        RelightLevel::Given
    );
    let range = |args: &[&str]| match parse(args).map(|c| c.command) {
        Ok(Command::Edit(EditArgs { range, .. })) => range,
        _ => panic!("{args:?} not parsed"),
    };
    assert_eq!(range(&[]), None);
    assert_eq!(range(&["--range", "clip"]), Some(Range::Clip));
    assert!(parse(&["--range", "hdr"]).is_err());
    let estimate = |args: &[&str]| match parse(args).map(|c| c.command) {
        Ok(Command::Edit(EditArgs { light_estimate, .. })) => light_estimate,
        _ => panic!("{args:?} not parsed"),
    };
    assert_eq!(estimate(&[]), LightEstimate::Auto);
    assert_eq!(estimate(&["--light-estimate", "network"]), LightEstimate::Network);
    let e = parse(&["--light-estimate", "guess"]).err().map(|e| e.to_string());
    assert!(e.is_some_and(|e| e.contains("--light-estimate")));
    let best = [(true, false), (true, true), (false, true), (false, false)].map(|(m, l)| Composite::best_for(m, l));
    assert_eq!(
        best,
        [
            Composite::Ratio,
            Composite::Ratio,
            Composite::Detail,
            Composite::Structure
        ]
    );
    // So do transfer and swap, for either object; Eq. 6 is refused with any of them.
    let pair = |cmd: &str, x: &str, y: &str, args: &[&str]| {
        let base = ["matedit", cmd, "--model", "m", x, "p.png", y, "q.png", "--out", "o"];
        Cli::try_parse_from(base.iter().chain(args)).map(|c| c.command)
    };
    for (cmd, x, y, own) in [
        ("transfer", "--from", "--to", ["--from-material", "--to-material"]),
        ("swap", "--a", "--b", ["--a-material", "--b-material"]),
    ] {
        let finish = |args: &[&str]| match pair(cmd, x, y, args) {
            Ok(Command::Transfer(TransferArgs { finish, .. }) | Command::Swap(SwapArgs { finish, .. })) => {
                finish.light_estimate
            }
            _ => panic!("{cmd} {args:?} not parsed"),
        };
        assert_eq!(finish(&[]), LightEstimate::Auto);
        assert_eq!(finish(&["--light-estimate", "network"]), LightEstimate::Network);
        assert!(pair(cmd, x, y, &["--light-estimate", "guess"]).is_err());
        for o in own {
            assert!(pair(cmd, x, y, &[o, "lambert:0.2,0.2,0.2"]).is_ok(), "{cmd} {o}");
            let e = pair(cmd, x, y, &[o, "lambert:0.2,0.2,0.2", "--optimize"])
                .err()
                .unwrap_or_else(|| panic!("{cmd} {o} with --optimize accepted"));
            assert!(e.to_string().contains(o), "{e}");
        }
    }
    // Either object's normals reach its side (and are Eq. 6's start, as edit's --normals).
    let normals = |c| match c {
        Command::Transfer(TransferArgs {
            from_normals,
            to_normals,
            ..
        }) => [from_normals, to_normals],
        Command::Swap(SwapArgs {
            a_normals, b_normals, ..
        }) => [a_normals, b_normals],
        _ => panic!("not a pair"),
    };
    for (cmd, x, y, own) in [
        ("transfer", "--from", "--to", ["--from-normals", "--to-normals"]),
        ("swap", "--a", "--b", ["--a-normals", "--b-normals"]),
    ] {
        for (k, o) in own.iter().enumerate() {
            let c = pair(cmd, x, y, &[o, "n.exr", "--optimize"]).unwrap_or_else(|e| panic!("{cmd} {o}: {e}"));
            let mut want = [None, None];
            want[k] = Some(PathBuf::from("n.exr"));
            assert_eq!(normals(c), want, "{cmd} {o}");
        }
    }
    // The object's known material is held: Eq. 6, which would change it, is refused with it.
    assert!(parse(&["--input-material", "library:red-plastic"]).is_ok());
    let e = parse(&["--input-material", "lambert:0.2,0.2,0.2", "--eq6"])
        .err()
        .expect("--input-material with --eq6 accepted");
    assert!(e.to_string().contains("--input-material"), "{e}");
}

#[test]
fn serve_limits_outside_their_ranges_are_refused() {
    let serve = |args: &[&str]| Cli::try_parse_from(["matedit", "serve", "--model", "m"].iter().chain(args));
    assert!(serve(&["--max-upload-mb", "0"]).is_err());
    assert!(serve(&["--max-upload-mb", "4097"]).is_err());
    assert!(serve(&["--queue", "1025"]).is_err());
    assert!(serve(&["--queue", "0"]).is_err());
    assert!(serve(&["--queue", "1", "--max-upload-mb", "1"]).is_ok());
    for (option, value) in [
        ("--keep", "0"),
        ("--keep", "10001"),
        ("--max-megapixels", "0"),
        ("--max-megapixels", "NaN"),
        ("--max-megapixels", "-1"),
        ("--upload-seconds", "0"),
        ("--allow-host", "evil.example:80"),
        ("--allow-host", "http://x"),
        ("--allow-host", ""),
    ] {
        let e = serve(&[option, value])
            .err()
            .unwrap_or_else(|| panic!("{option} {value:?} accepted"));
        assert!(e.to_string().contains(option), "{option} {value}: {e}");
    }
    assert!(serve(&["--keep", "1", "--max-megapixels", "0.5", "--allow-host", "Studio.lan"]).is_ok());
}
