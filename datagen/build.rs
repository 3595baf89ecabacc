//! The git commit the factory is built from (`MATEDIT_GIT_COMMIT`, recorded in every dataset's
//! `plan.json`): from `git rev-parse HEAD`, or the variable of that name where the source is not
//! a git checkout, else `unknown`.
//!
//! With the `embree` feature: where libembree4 is (`EMBREE_DIR`, from scripts/install_embree.sh),
//! for the linker and, as an rpath, for datagen's own binary and tests at run time.

fn main() {
    commit();
    println!("cargo:rerun-if-env-changed=EMBREE_DIR");
    if std::env::var_os("CARGO_FEATURE_EMBREE").is_none() {
        return;
    }
    match std::env::var("EMBREE_DIR") {
        Ok(dir) => {
            println!("cargo:rustc-link-search=native={dir}");
            println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
        }
        Err(_) => println!(
            "cargo:warning=the embree feature needs EMBREE_DIR (eval \"$(scripts/install_embree.sh)\"); linking against a system libembree4"
        ),
    }
}

fn git(args: &[&str]) -> Option<String> {
    let out = std::process::Command::new("git").args(args).output().ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    (out.status.success() && !text.trim().is_empty()).then(|| text.trim().to_string())
}

fn commit() {
    println!("cargo:rerun-if-env-changed=MATEDIT_GIT_COMMIT");
    let given = std::env::var("MATEDIT_GIT_COMMIT").ok().filter(|c| !c.is_empty());
    let commit = given
        .or_else(|| git(&["rev-parse", "HEAD"]))
        .unwrap_or_else(|| "unknown".into());
    // Rebuilt when HEAD moves: HEAD itself (a checkout) and the branch it names (a commit).
    for path in ["HEAD", "packed-refs"] {
        if let Some(p) = git(&["rev-parse", "--git-path", path]) {
            println!("cargo:rerun-if-changed={p}");
        }
    }
    if let Some(branch) = git(&["symbolic-ref", "-q", "HEAD"])
        && let Some(p) = git(&["rev-parse", "--git-path", &branch])
    {
        println!("cargo:rerun-if-changed={p}");
    }
    println!("cargo:rustc-env=MATEDIT_GIT_COMMIT={commit}");
}
