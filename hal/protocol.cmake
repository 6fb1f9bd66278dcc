# pmsm_protocol: the CAN protocol shared by pmsm-thermald and pmsm-plant (pure: no OS calls).
#   protocol.hpp   the one definition of every frame and signal (compile-time checked)
#   codec.hpp      typed encode/decode, CRC-8 + alive counter, per-role receivers
#   protocol_filters.hpp  kernel receive filters per role
#   dbc_writer.hpp generated DBC and docs tables (pmsm-dbc-gen)
#   dbc.hpp, candump.hpp  independent DBC reader/decoder and candump line parser
add_library(pmsm_protocol STATIC
  ${CMAKE_CURRENT_LIST_DIR}/src/protocol/protocol.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/protocol/codec.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/protocol/filters.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/protocol/dbc_writer.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/protocol/dbc_reader.cpp
  ${CMAKE_CURRENT_LIST_DIR}/src/protocol/candump.cpp)
add_library(pmsm::protocol ALIAS pmsm_protocol)
target_link_libraries(pmsm_protocol PUBLIC pmsm_messages)
pmsm_target_defaults(pmsm_protocol)

# Regenerates the committed DBC (node 0) and the frame tables of docs/protocol.md.
add_executable(pmsm-dbc-gen ${CMAKE_CURRENT_LIST_DIR}/src/protocol/tools/dbc_gen_main.cpp)
target_link_libraries(pmsm-dbc-gen PRIVATE pmsm_protocol)
pmsm_target_defaults(pmsm-dbc-gen)

add_custom_target(pmsm-protocol-regen
  COMMAND pmsm-dbc-gen --dbc ${PROJECT_SOURCE_DIR}/can/pmsm-thermal.dbc
                       --docs ${PROJECT_SOURCE_DIR}/docs/protocol.md
  DEPENDS pmsm-dbc-gen
  COMMENT "Regenerating can/pmsm-thermal.dbc and docs/protocol.md from protocol.hpp"
  VERBATIM)
