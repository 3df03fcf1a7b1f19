//! CPU time, for measurements that should not depend on what else runs on the machine:
//! `pinrender bench` times its single-thread rows by the thread's CPU time, `pinrender eval
//! --clock cpu` its budgets by the process's. Both are `NaN` if the clock cannot be read, and
//! each caller falls back to wall time then.

/// CPU time of the calling thread (`CLOCK_THREAD_CPUTIME_ID`), in seconds.
pub fn thread_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec and the clock id is a constant Linux knows.
    if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// User + system time of the whole process, every thread (`getrusage(RUSAGE_SELF)`), in
/// seconds.
pub fn process_s() -> f64 {
    // SAFETY: an all-zero rusage is a valid value of the plain C struct, and getrusage only
    // writes into the struct it is given.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `ru` is a valid, writable rusage and RUSAGE_SELF is a constant Linux knows.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) } != 0 {
        return f64::NAN;
    }
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

#[cfg(test)]
mod tests {
    #[test]
    fn both_clocks_advance_with_work() {
        let (t0, p0) = (super::thread_s(), super::process_s());
        let mut x = 0u64;
        for i in 0..20_000_000u64 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(i));
        }
        std::hint::black_box(x);
        assert!(super::thread_s() > t0, "thread clock");
        assert!(super::process_s() > p0, "process clock");
    }
}
