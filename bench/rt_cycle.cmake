# pmsm_rt_cycle: the control loop's deadlines at the drive's own rate on this host, natively
# (SCHED_FIFO on hal::PeriodicTimer, DriveNode::step on a scenario's closed loop, no bus);
# docs/performance.md, "Deadlines at 10 kHz on this host".
add_executable(pmsm_rt_cycle ${CMAKE_CURRENT_LIST_DIR}/rt_cycle.cpp)
pmsm_target_defaults(pmsm_rt_cycle)
target_include_directories(pmsm_rt_cycle PRIVATE ${CMAKE_CURRENT_LIST_DIR})
target_link_libraries(pmsm_rt_cycle PRIVATE pmsm_sim pmsm_drive pmsm::plant pmsm::core pmsm::hal)
# The tool runs and reports (a fraction of a second; timing is never asserted).
add_test(NAME rt_cycle_smoke
  COMMAND pmsm_rt_cycle ${PROJECT_SOURCE_DIR}/bench/scenarios/reference-fm-bipolar.toml 0.2)
set_tests_properties(rt_cycle_smoke PROPERTIES LABELS bench TIMEOUT 60
  PASS_REGULAR_EXPRESSION "2000 stepped periods.*deadline misses: [0-9]+ of [0-9]+ deadlines.*floor: [0-9]+ of [0-9]+ deadlines")
