// GYROTHERM_AVX2_CLONES: marks a hot loop to be compiled twice, for AVX2/FMA
// (x86-64-v3) and the baseline, the copy chosen at load time by an ifunc
// resolver. Under ThreadSanitizer it marks nothing: the sanitizer instruments
// the resolver, which the dynamic loader runs before the sanitizer's runtime
// is up, and the program crashes at start (clang 14).
#pragma once

#if defined(__SANITIZE_THREAD__)
#define GYROTHERM_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define GYROTHERM_TSAN 1
#endif
#endif

#if defined(GYROTHERM_TSAN) || !defined(__x86_64__)
#define GYROTHERM_AVX2_CLONES
#else
#define GYROTHERM_AVX2_CLONES [[gnu::target_clones("arch=x86-64-v3", "default")]]
#endif
