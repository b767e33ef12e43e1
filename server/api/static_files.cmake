# Included from server/CMakeLists.txt: embeds the preview page (client/preview/)
# and the bundled examples (examples/*.json) into tally_server_lib. Editing one of
# them regenerates static_assets.cpp at build time; adding or removing one is
# picked up by the CONFIGURE_DEPENDS globs.
file(GLOB_RECURSE tally_static_preview CONFIGURE_DEPENDS RELATIVE ${PROJECT_SOURCE_DIR}
     ${PROJECT_SOURCE_DIR}/client/preview/*.html ${PROJECT_SOURCE_DIR}/client/preview/*.js
     ${PROJECT_SOURCE_DIR}/client/preview/*.css ${PROJECT_SOURCE_DIR}/client/preview/*.svg
     ${PROJECT_SOURCE_DIR}/client/preview/*.png ${PROJECT_SOURCE_DIR}/client/preview/*.txt)
file(GLOB tally_static_examples CONFIGURE_DEPENDS RELATIVE ${PROJECT_SOURCE_DIR}
     ${PROJECT_SOURCE_DIR}/examples/*.json)
set(tally_static_files ${tally_static_preview} ${tally_static_examples})
list(SORT tally_static_files)
set(tally_static_abs "")
foreach(f IN LISTS tally_static_files)
  list(APPEND tally_static_abs ${PROJECT_SOURCE_DIR}/${f})
endforeach()
string(REPLACE ";" "|" tally_static_arg "${tally_static_files}")
set(tally_static_out ${CMAKE_CURRENT_BINARY_DIR}/static_assets.cpp)
add_custom_command(
  OUTPUT ${tally_static_out}
  COMMAND ${CMAKE_COMMAND} -DROOT=${PROJECT_SOURCE_DIR} -DOUT=${tally_static_out} "-DFILES=${tally_static_arg}"
          -P ${CMAKE_CURRENT_LIST_DIR}/embed_static.cmake
  DEPENDS ${tally_static_abs} ${CMAKE_CURRENT_LIST_DIR}/embed_static.cmake
  COMMENT "Embedding the preview page and examples"
  VERBATIM)
target_sources(tally_server_lib PRIVATE ${tally_static_out})
