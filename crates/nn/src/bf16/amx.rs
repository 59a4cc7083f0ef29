//! The AMX product (see the module doc in mod.rs).
#![allow(unsafe_code)]

use std::arch::asm;
use std::arch::x86_64::__cpuid_count;
use std::sync::OnceLock;

/// AMX-TILE and AMX-BF16 in CPUID, and Linux's permission for the tile data granted.
pub(crate) fn available() -> bool {
    static OK: OnceLock<bool> = OnceLock::new();
    *OK.get_or_init(|| {
        // CPUID leaf 7, subleaf 0, EDX: bit 22 AMX-BF16, bit 24 AMX-TILE.
        let edx = __cpuid_count(7, 0).edx;
        if edx & (1 << 22) == 0 || edx & (1 << 24) == 0 {
            return false;
        }
        let ret: i64;
        // SAFETY: arch_prctl(ARCH_REQ_XCOMP_PERM = 0x1023, XFEATURE_XTILEDATA = 18) only
        // asks the kernel to allow the tile state in this process; it touches no memory.
        unsafe {
            asm!("syscall", inlateout("rax") 158i64 => ret, in("rdi") 0x1023i64, in("rsi") 18i64,
                 lateout("rcx") _, lateout("r11") _, options(nostack));
        }
        ret == 0
    })
}

/// The tile configuration: palette 1; tmm0-3 the 2 x 2 tiles of C (16 rows of 16 f32),
/// tmm4-5 two tiles of A and tmm6-7 two of B (16 rows of 64 bytes each).
#[repr(C, align(64))]
struct Config([u8; 64]);

fn config() -> Config {
    let mut c = [0u8; 64];
    c[0] = 1;
    for t in 0..8 {
        c[16 + 2 * t..18 + 2 * t].copy_from_slice(&64u16.to_le_bytes());
        c[48 + t] = 16;
    }
    Config(c)
}

/// C (m x n, row-major) = or += A B from packed A (`m32` rows of `kp16` pairs, row stride
/// lda) and packed B (`kp16` rows of `n32` pairs, stride ldb), zero-padded to whole tiles.
///
/// # Safety
/// `available()` is true; the packed buffers have the sizes above; `c` is m x n.
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn product(
    c: &mut [f32],
    accumulate: bool,
    m: usize,
    n: usize,
    kp16: usize,
    lda: usize,
    ldb: usize,
    a: &[u32],
    b: &[u32],
) {
    let cfg = config();
    let mut out = [0f32; 32 * 32];
    let (sa, sb, so) = (4 * lda, 4 * ldb, 4 * 32usize);
    // SAFETY: loads the configuration above (valid for palette 1).
    unsafe { asm!("ldtilecfg [{}]", in(reg) cfg.0.as_ptr(), options(nostack)) };
    for i0 in (0..m).step_by(32) {
        for j0 in (0..n).step_by(32) {
            // SAFETY: every tile load reads 16 rows of 64 bytes inside the padded buffers
            // (rows i0..i0 + 32 < m32 of A, pair rows < kp16 of B, columns j0..j0 + 32 <= n32);
            // the stores write the 32 x 32 f32 of `out`.
            unsafe {
                asm!("tilezero tmm0", "tilezero tmm1", "tilezero tmm2", "tilezero tmm3", options(nostack));
                for q in (0..kp16).step_by(16) {
                    let a0 = a.as_ptr().add(i0 * lda + q);
                    let a1 = a.as_ptr().add((i0 + 16) * lda + q);
                    let b0 = b.as_ptr().add(q * ldb + j0);
                    let b1 = b.as_ptr().add(q * ldb + j0 + 16);
                    asm!(
                        "tileloadd tmm4, [{a0} + {sa} * 1]",
                        "tileloadd tmm5, [{a1} + {sa} * 1]",
                        "tileloadd tmm6, [{b0} + {sb} * 1]",
                        "tileloadd tmm7, [{b1} + {sb} * 1]",
                        "tdpbf16ps tmm0, tmm4, tmm6",
                        "tdpbf16ps tmm1, tmm4, tmm7",
                        "tdpbf16ps tmm2, tmm5, tmm6",
                        "tdpbf16ps tmm3, tmm5, tmm7",
                        a0 = in(reg) a0, a1 = in(reg) a1, b0 = in(reg) b0, b1 = in(reg) b1,
                        sa = in(reg) sa, sb = in(reg) sb, options(nostack, readonly),
                    );
                }
                let o = out.as_mut_ptr();
                asm!(
                    "tilestored [{o0} + {so} * 1], tmm0",
                    "tilestored [{o1} + {so} * 1], tmm1",
                    "tilestored [{o2} + {so} * 1], tmm2",
                    "tilestored [{o3} + {so} * 1], tmm3",
                    o0 = in(reg) o, o1 = in(reg) o.add(16), o2 = in(reg) o.add(16 * 32), o3 = in(reg) o.add(16 * 32 + 16),
                    so = in(reg) so, options(nostack),
                );
            }
            for r in 0..32.min(m - i0) {
                let cols = 32.min(n - j0);
                let dst = &mut c[(i0 + r) * n + j0..(i0 + r) * n + j0 + cols];
                let src = &out[r * 32..r * 32 + cols];
                if accumulate {
                    dst.iter_mut().zip(src).for_each(|(d, s)| *d += s);
                } else {
                    dst.copy_from_slice(src);
                }
            }
        }
    }
    // SAFETY: releases the tile state this function configured.
    unsafe { asm!("tilerelease", options(nostack)) };
}
