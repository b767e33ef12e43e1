cmake_minimum_required(VERSION 3.20)
# The layering docs/architecture.md promises, checked on the sources' #include lines.
# Exits non-zero (FATAL_ERROR) naming every offending line when a rule is broken:
#   json     the engine and the job kinds speak types : only the spec readers
#            listed below may include nlohmann-json, common/spec, a job kind's spec reader
#            or the scene reader's header;
#   views    nothing under common/engine, common/integrate, common/lighting or common/spec
#            includes the JSON views or the kinds' table (common/protocol), spec readers
#            included;
#   http     server/http is the transport: it includes only itself (and common/log),
#            and names no application type (the caller, jobs: http-names);
#   auth     server/auth includes nothing of server/api (it uses the http vocabulary);
#   cluster  server/cluster (an Executor, and tally-worker) includes nothing of server/api,
#            jobs, auth or assets: it sits beside the in-process executor, below the routes;
#   cli      server/cli (flags the two binaries share) includes nothing of server/ but
#            server/host;
#   size     no file under server/jobs is longer than MAX_LINES (600: no god object,
#            issue 26; each part of the job lifecycle in a file of its own).
#   cmake -DROOT=<source dir> [-DMAX_LINES=600] -P layering.cmake
if(NOT ROOT)
  message(FATAL_ERROR "pass -DROOT=<source dir>")
endif()
get_filename_component(ROOT "${ROOT}" ABSOLUTE)

set(bad "")
set(checked 0)
# check(<rule> <pattern list var> <allowed files var> <globs...>): every line of every
# file matched by the globs (paths relative to ROOT) that matches one of the patterns is
# a violation unless the file is in the allowed list.
function(check rule patterns_var allowed_var)
  set(globs)
  foreach(g IN LISTS ARGN)
    list(APPEND globs ${ROOT}/${g})
  endforeach()
  file(GLOB_RECURSE files RELATIVE ${ROOT} ${globs})
  list(LENGTH files n)
  math(EXPR total "${checked} + ${n}")
  set(checked ${total} PARENT_SCOPE)
  set(found "")
  foreach(f IN LISTS files)
    if(f IN_LIST ${allowed_var})
      continue()
    endif()
    file(STRINGS ${ROOT}/${f} lines)
    foreach(line IN LISTS lines)
      foreach(p IN LISTS ${patterns_var})
        if(line MATCHES "${p}")
          string(APPEND found "\n  [${rule}] ${f}: ${line}")
          break()
        endif()
      endforeach()
    endforeach()
  endforeach()
  set(bad "${bad}${found}" PARENT_SCOPE)
endfunction()

set(engine_and_kinds
  common/engine/*.hpp common/engine/*.cpp
  common/integrate/*.hpp common/integrate/*.cpp
  common/lighting/*.hpp common/lighting/*.cpp)

set(spec_readers
  common/integrate/integration_spec.hpp common/integrate/integration_spec.cpp
  common/lighting/lighting_spec.hpp common/lighting/lighting_spec.cpp
  common/lighting/scene_json.hpp common/lighting/scene_json.cpp
  common/lighting/gltf_scene.cpp       # scene reader: glTF files, errors are SpecErrors
  common/lighting/gltf_census.hpp common/lighting/gltf_census.cpp  # scene reader: a glTF's JSON counted before it is parsed
  common/lighting/obj_scene.cpp        # scene reader: OBJ + .mtl files, errors are SpecErrors
  common/lighting/asset_resolver.hpp common/lighting/asset_resolver.cpp)  # scene file names -> files, errors are SpecErrors
set(json_patterns "<nlohmann/" "nlohmann::" "\"common/protocol/" "\"common/spec/" "_spec\\.hpp\""
  "scene_json\\.hpp\"")
check(json json_patterns spec_readers ${engine_and_kinds})

set(none "")
set(views_patterns "#include[ \t]*\"common/protocol/")
check(views views_patterns none ${engine_and_kinds} common/spec/*.hpp common/spec/*.cpp)

set(http_patterns "#include[ \t]*\"(server/([^h]|h[^t]|ht[^t]|htt[^p]|http[^/])|common/([^l]|l[^o]|lo[^g]|log[^/])|client/)")
check(http http_patterns none server/http/*.hpp server/http/*.cpp)
set(http_name_patterns "(^|[^A-Za-z_])(Principal|Submitter|JobManager|JobSnapshot|Job)([^A-Za-z_]|$)")
check(http-names http_name_patterns none server/http/*.hpp server/http/*.cpp)

set(auth_patterns "#include[ \t]*\"server/api/")
check(auth auth_patterns none server/auth/*.hpp server/auth/*.cpp)

set(cluster_patterns "#include[ \t]*\"server/(api|jobs|auth|assets)/")
check(cluster cluster_patterns none server/cluster/*.hpp server/cluster/*.cpp)

set(cli_patterns "#include[ \t]*\"server/([^hc]|h[^o]|ho[^s]|hos[^t]|host[^/]|c[^l]|cl[^i]|cli[^/])")
check(cli cli_patterns none server/cli/*.hpp server/cli/*.cpp)

if(NOT MAX_LINES)
  set(MAX_LINES 600)
endif()
file(GLOB_RECURSE sized RELATIVE ${ROOT} ${ROOT}/server/jobs/*.hpp ${ROOT}/server/jobs/*.cpp)
foreach(f IN LISTS sized)
  file(READ ${ROOT}/${f} text)
  string(REGEX MATCHALL "\n" newlines "${text}")
  list(LENGTH newlines n)
  if(n GREATER MAX_LINES)
    string(APPEND bad "\n  [size] ${f}: ${n} lines (at most ${MAX_LINES})")
  endif()
endforeach()

if(checked EQUAL 0)
  message(FATAL_ERROR "no sources under ${ROOT}")
endif()
if(bad)
  message(FATAL_ERROR "layering broken:${bad}")
endif()
message(STATUS "${checked} files checked: the engine and job kinds speak no JSON, nothing below "
  "common/protocol includes it, server/http includes only itself and names no application type, server/auth nothing of server/api, "
  "server/cluster nothing of api, jobs, auth or assets, server/cli only server/host, "
  "no file under server/jobs over ${MAX_LINES} lines")
