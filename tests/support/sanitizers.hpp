// Whether this translation unit is built with AddressSanitizer: PMSM_TEST_ASAN is 1 or 0.
// GCC defines __SANITIZE_ADDRESS__; clang 14 says it through __has_feature.
#pragma once

#if defined(__SANITIZE_ADDRESS__)
#define PMSM_TEST_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define PMSM_TEST_ASAN 1
#endif
#endif
#ifndef PMSM_TEST_ASAN
#define PMSM_TEST_ASAN 0
#endif
