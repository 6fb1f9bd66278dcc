# The CAN protocol: CRC-8, codec round trips and rejections, receive filters, DBC agreement
# (committed DBC and docs equal to the generated ones), candump parsing. All label unit.
pmsm_add_gtest(protocol_codec_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/protocol_codec_test.cpp
  LIBS pmsm::protocol_tools)

pmsm_add_gtest(protocol_dbc_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/protocol_dbc_test.cpp
  LIBS pmsm::protocol_tools)

pmsm_add_gtest(protocol_candump_test LABEL unit
  SOURCES ${CMAKE_CURRENT_LIST_DIR}/protocol_candump_test.cpp
  LIBS pmsm::protocol_tools)

# pmsm-dbc-gen's command line: --check on the committed files, and what it cannot check named.
add_test(NAME dbc_gen_cli
  COMMAND ${CMAKE_CURRENT_LIST_DIR}/dbc_gen_cli.sh ${PROJECT_SOURCE_DIR} $<TARGET_FILE:pmsm-dbc-gen>)
set_tests_properties(dbc_gen_cli PROPERTIES LABELS unit)
