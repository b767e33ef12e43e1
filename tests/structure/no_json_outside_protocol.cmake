cmake_minimum_required(VERSION 3.20)
# Fails when a file of the engine or the job kinds speaks JSON (issue 10): only
# common/protocol and the spec readers listed below may include nlohmann-json, the
# protocol headers, or a spec reader's header.
#   cmake -DROOT=<source dir> -P no_json_outside_protocol.cmake
if(NOT ROOT)
  message(FATAL_ERROR "pass -DROOT=<source dir>")
endif()
set(allowed
  common/integrate/integration_spec.hpp common/integrate/integration_spec.cpp
  common/lighting/lighting_spec.hpp common/lighting/lighting_spec.cpp
  common/lighting/scene_json.hpp common/lighting/scene_json.cpp
  common/lighting/gltf_scene.cpp       # scene reader: glTF files, errors are SpecErrors
  common/lighting/gltf_census.cpp      # scene reader: a glTF's JSON counted before it is parsed
  common/lighting/obj_scene.cpp        # scene reader: OBJ + .mtl files, errors are SpecErrors
  common/lighting/asset_resolver.hpp common/lighting/asset_resolver.cpp  # scene file names -> files, errors are SpecErrors
  common/jobs/job_factory.hpp common/jobs/job_factory.cpp)
set(patterns "<nlohmann/" "nlohmann::" "\"common/protocol/" "_spec\\.hpp\"" "scene_json\\.hpp\"" "job_factory\\.hpp\"")
file(GLOB_RECURSE files RELATIVE ${ROOT}
  ${ROOT}/common/engine/*.hpp ${ROOT}/common/engine/*.cpp
  ${ROOT}/common/integrate/*.hpp ${ROOT}/common/integrate/*.cpp
  ${ROOT}/common/lighting/*.hpp ${ROOT}/common/lighting/*.cpp
  ${ROOT}/common/jobs/*.hpp ${ROOT}/common/jobs/*.cpp)
list(LENGTH files n)
if(n EQUAL 0)
  message(FATAL_ERROR "no engine or job-kind sources under ${ROOT}")
endif()
set(bad "")
foreach(f IN LISTS files)
  if(f IN_LIST allowed)
    continue()
  endif()
  file(STRINGS ${ROOT}/${f} lines)
  foreach(line IN LISTS lines)
    foreach(p IN LISTS patterns)
      if(line MATCHES "${p}")
        string(APPEND bad "\n  ${f}: ${line}")
      endif()
    endforeach()
  endforeach()
endforeach()
if(bad)
  message(FATAL_ERROR "JSON outside common/protocol and the spec readers:${bad}")
endif()
message(STATUS "${n} engine and job-kind files checked: no JSON outside the spec readers")
