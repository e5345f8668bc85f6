//! Third-party decoders on untrusted bytes: a panic inside one becomes an error.
//!
//! The Parquet decoder panics on some corrupt files ("column start and length should not be
//! negative", an index out of bounds, "Decoder for dict should have been set": found by
//! `tests/fuzz`). A lab's damaged file must give a message and exit code 2, not a crash, so the
//! readers run the decoder through [`decode`]. While it runs, the panic message is not printed
//! (a hook installed once forwards every other panic to the previous hook).

use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Once;

thread_local! {
    static DECODING: Cell<bool> = const { Cell::new(false) };
}

fn install_hook() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !DECODING.with(Cell::get) {
                previous(info);
            }
        }));
    });
}

/// Runs `f`; a panic inside it is returned as `Err(message)`.
pub fn decode<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    install_hook();
    let was = DECODING.with(|d| d.replace(true));
    let result = catch_unwind(AssertUnwindSafe(f));
    DECODING.with(|d| d.set(was));
    result.map_err(|p| {
        p.downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| (*s).to_string()))
            .unwrap_or_else(|| "unknown failure".to_string())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_its_message_and_a_value_passes_through() {
        assert_eq!(decode(|| 3), Ok(3));
        let e = decode(|| -> i32 { panic!("column start and length should not be negative") });
        assert_eq!(e, Err("column start and length should not be negative".to_string()));
        // Nested: the outer guard stays active after the inner one ends.
        let nested = decode(|| {
            let _ = decode(|| 1);
            panic!("after")
        });
        assert_eq!(nested, Err::<(), _>("after".to_string()));
    }
}
