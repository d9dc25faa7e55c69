#!/usr/bin/env bash
# install-mocap-clips.sh: Debian's assimp-testmodels for the motion-capture tests, when missing:
# it ships three public BVH clips (CMU 01_01 and 01_03 in the cgspeed conversion, Boxing_Toes)
# under /usr/share/assimp/models/BVH/.
set -uo pipefail
here=$(dirname "$0")
[ -d /usr/share/assimp/models/BVH ] && exit 0
"$here/apt-install.sh" assimp-testmodels
