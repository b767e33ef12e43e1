#!/bin/sh
# Ad-hoc load on a running server: wrk against GET /v1/jobs/{id}.
# Usage: bench/wrk/get_job.sh http://127.0.0.1:8080 JOB_ID [wrk args...]
set -eu
url=$1; id=$2; shift 2
exec wrk -t1 -c32 -d10s "$@" "$url/v1/jobs/$id"
