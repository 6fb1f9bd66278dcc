# The control step by step class in pmsm_speed_bench (bench/step_bench.cpp), on the replay
# pmsm_step_cost counts instructions on (bench/step_replay.hpp).
target_sources(pmsm_speed_bench PRIVATE ${CMAKE_CURRENT_LIST_DIR}/step_bench.cpp)
target_include_directories(pmsm_speed_bench PRIVATE ${CMAKE_CURRENT_LIST_DIR})
target_link_libraries(pmsm_speed_bench PRIVATE pmsm_sim pmsm_drive)
