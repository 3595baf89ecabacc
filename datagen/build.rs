//! With the `embree` feature: where libembree4 is (`EMBREE_DIR`, from scripts/install_embree.sh),
//! for the linker and, as an rpath, for datagen's own binary and tests at run time.

fn main() {
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
