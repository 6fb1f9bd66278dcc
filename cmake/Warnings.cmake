# Strict warnings, set once for every target of the project (pmsm_target_defaults).
set(PMSM_WARNINGS
  -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wsign-conversion -Wold-style-cast
  -Wnon-virtual-dtor -Woverloaded-virtual -Wcast-align -Wnull-dereference
  -Wdouble-promotion -Wformat=2 -Wimplicit-fallthrough -Wmisleading-indentation
  -Wduplicated-cond -Wduplicated-branches -Wlogical-op -Wuseless-cast)
if(CMAKE_CXX_COMPILER_ID MATCHES "Clang")
  # GCC's only; clang (the asan preset) has no such warnings.
  list(REMOVE_ITEM PMSM_WARNINGS -Wduplicated-cond -Wduplicated-branches -Wlogical-op -Wuseless-cast)
endif()

if(PMSM_FUZZ)
  if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
    message(FATAL_ERROR "PMSM_FUZZ needs clang (libFuzzer): use the asan preset (clang++-14, libclang-rt-14-dev)")
  endif()
  # Every library the fuzzers link is instrumented for coverage and checked by ASan + UBSan;
  # only the fuzz targets link libFuzzer's main (tests/fuzz/CMakeLists.txt). The tests of the
  # same build carry the coverage hooks unused (the sanitizer runtime's defaults).
  add_compile_options(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
elseif(PMSM_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all)
  add_link_options(-fsanitize=address,undefined)
endif()

function(pmsm_target_defaults target)
  target_compile_options(${target} PRIVATE ${PMSM_WARNINGS})
  # No fused multiply-adds the source does not write: the simulator's figures are the same to
  # the last digit in every build only while each expression rounds as written (a build with
  # -march=x86-64-v3 would otherwise contract a·b + c; docs/performance.md, "Bit for bit").
  target_compile_options(${target} PRIVATE -ffp-contract=off)
  if(PMSM_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
  target_compile_features(${target} PUBLIC cxx_std_20)
endfunction()
