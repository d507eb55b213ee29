//! A dependency's panic that the library catches and reports as an error
//! prints nothing: the panic hook (which prints `panicked at` and, with
//! `RUST_BACKTRACE=1`, a backtrace) is not called for it, while every other
//! panic still reaches the hook that was there before. One test in its own
//! binary: it sets the process's panic hook.
#![allow(clippy::unwrap_used, reason = "tests")]

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

#[test]
fn a_caught_panic_reaches_no_hook_and_any_other_does() {
    let calls = Arc::new(AtomicUsize::new(0));
    let seen = Arc::clone(&calls);
    std::panic::set_hook(Box::new(move |_| {
        seen.fetch_add(1, Ordering::SeqCst);
    }));
    let caught = tissue_core::io::catch_quietly(|| -> u32 { panic!("a damaged file") });
    assert!(caught.is_err());
    assert_eq!(
        calls.load(Ordering::SeqCst),
        0,
        "the hook heard a caught panic"
    );
    assert_eq!(tissue_core::io::catch_quietly(|| 7).unwrap(), 7);

    // A panic not caught quietly (here on another thread) is heard.
    let other = std::thread::spawn(|| panic!("a bug")).join();
    assert!(other.is_err());
    assert_eq!(calls.load(Ordering::SeqCst), 1);

    // Nested: the inner catch leaves the outer one quiet.
    let nested = tissue_core::io::catch_quietly(|| {
        let inner = tissue_core::io::catch_quietly(|| panic!("inner"));
        assert!(inner.is_err());
        panic!("outer")
    });
    assert!(nested.is_err());
    assert_eq!(calls.load(Ordering::SeqCst), 1);
}
