# pmsm_speed_bench: the speed figures of DESIGN §9 that do not need a bus, in one Google
# Benchmark binary (no timing assertions anywhere: these are measurements, see docs/hil.md).
#   build/<dir>/bench/pmsm_speed_bench [--benchmark_filter=Plant] [--benchmark_repetitions=5]
#
# plant_bench.cpp     plant step (reference and ideal profiles, standstill and at speed),
#                     truth/state snapshot, lockstep PlantNode over the in-process bus
# protocol_bench.cpp  codec encode/decode of the fast frames, E2E CRC, DaemonReceiver and
#                     PlantReceiver receive
#
# Other areas add their benchmarks to the same binary from a list file of their own that
# sorts after this one (bench/CMakeLists.txt includes bench/*.cmake in order), e.g.
# bench/speed_controller.cmake:
#   target_sources(pmsm_speed_bench PRIVATE ${CMAKE_CURRENT_LIST_DIR}/controller_bench.cpp)
#   target_link_libraries(pmsm_speed_bench PRIVATE pmsm_drive)
add_executable(pmsm_speed_bench
  ${CMAKE_CURRENT_LIST_DIR}/plant_bench.cpp
  ${CMAKE_CURRENT_LIST_DIR}/protocol_bench.cpp)
pmsm_target_defaults(pmsm_speed_bench)
target_compile_definitions(pmsm_speed_bench PRIVATE PMSM_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
target_link_libraries(pmsm_speed_bench PRIVATE
  pmsm_plant_node pmsm::plant pmsm::protocol pmsm::hal benchmark::benchmark benchmark::benchmark_main)

# Run once, briefly, so that the binary cannot rot unnoticed (label bench; no timing checked).
add_test(NAME pmsm_speed_bench_smoke
  COMMAND pmsm_speed_bench --benchmark_min_time=0.01 --benchmark_filter=.)
set_tests_properties(pmsm_speed_bench_smoke PROPERTIES LABELS bench TIMEOUT 120)
