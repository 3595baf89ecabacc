//! Value parsers for numeric command-line options, shared by `datagen`, `trainer` and `matedit`:
//! every numeric option has a documented range and is refused outside it, the error naming the
//! range (clap adds the option's name). Plain functions, so that they need no clap here.

/// A finite number in `[lo, hi]` (NaN and the infinities are outside every range).
pub fn finite_in(lo: f64, hi: f64) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| {
        let v: f64 = s.trim().parse().map_err(|_| format!("{s:?} is not a number"))?;
        if !(lo..=hi).contains(&v) {
            return Err(format!("{s:?} is outside {lo:e}–{hi:e}"));
        }
        Ok(v)
    }
}

/// A whole number in `[lo, hi]`.
pub fn count_in(lo: usize, hi: usize) -> impl Fn(&str) -> Result<usize, String> + Clone + Send + Sync + 'static {
    move |s: &str| {
        let v: usize = s.trim().parse().map_err(|_| format!("{s:?} is not a whole number"))?;
        if !(lo..=hi).contains(&v) {
            return Err(format!("{v} is outside {lo}–{hi}"));
        }
        Ok(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_hold_at_their_corners_and_refuse_everything_else() {
        let f = finite_in(-1.5, 1e6);
        for ok in ["-1.5", "1e6", "0", " 3.25 "] {
            assert!(f(ok).is_ok(), "{ok}");
        }
        for bad in ["-1.5000001", "1000000.1", "NaN", "inf", "-inf", "", "x", "1e400"] {
            let e = f(bad).unwrap_err();
            assert!(e.contains(&format!("{bad:?}")), "{bad}: {e}");
        }
        assert!(f("2e6").unwrap_err().contains("1e6"), "the range is printed short");
        let c = count_in(1, 100);
        assert_eq!((c("1"), c("100")), (Ok(1), Ok(100)));
        for bad in ["0", "101", "-1", "1.5", "", "18446744073709551616"] {
            assert!(c(bad).is_err(), "{bad}");
        }
    }
}
