#!/usr/bin/env bash
# Unpack GDAL 3.6 (ogrinfo, the Python bindings and GDAL's GeoPackage validator) into
# build/gdal36, idempotently, to check the GeoPackages towerpipe writes the way its users
# open them: GDAL 3.6 is the GDAL of QGIS LTR on Debian 12.
#
# Nothing is installed: the Debian 12 packages are fetched with `apt-get download` and
# unpacked into build/gdal36 (run the tools with LD_LIBRARY_PATH=build/gdal36/usr/lib/...).
# GDAL 3.6 cannot be installed beside PDAL 2.2 (scripts/install_pdal.sh): PDAL keeps
# Debian 11's libgeotiff5 and libspatialite7, linked to PROJ 7, and bookworm's ogrinfo
# then loads both PROJ 7 and PROJ 9 and crashes. The unpacked copy brings Debian 12's
# builds of those two libraries with it.
#
# Not Debian 12 -> a note, exit 0: the tests that need GDAL 3.6 skip with that reason.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

DEST=build/gdal36
if [ -x "$DEST/usr/bin/ogrinfo" ] && [ -f "$DEST/usr/lib/python3/dist-packages/osgeo_utils/samples/validate_gpkg.py" ]; then
  echo "gdal36_tools: $DEST already holds GDAL 3.6; nothing to do"
  exit 0
fi
. /etc/os-release 2>/dev/null || true
if [ "${ID:-}" != "debian" ] || [ "${VERSION_CODENAME:-}" != "bookworm" ]; then
  echo "gdal36_tools: not Debian 12; the GDAL 3.6 checks of the GeoPackages will be skipped"
  exit 0
fi

# the packages apt would add for gdal-bin and python3-gdal, plus bookworm's builds of the
# two libraries PDAL 2.2 pins to bullseye
mapfile -t PKGS < <(apt-get install -s -qq --no-install-recommends gdal-bin python3-gdal 2>/dev/null \
                    | awk '/^Inst /{print $2}')
PKGS+=(gdal-bin python3-gdal libgdal32 libgeotiff5/bookworm libspatialite7/bookworm)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
(cd "$tmp" && apt-get download -qq "${PKGS[@]}" 2>&1 | grep -v "unsandboxed\|^W: " || true)
rm -rf "$DEST.part"
mkdir -p "$DEST.part"
for deb in "$tmp"/*.deb; do
  dpkg-deb -x "$deb" "$DEST.part"
done
rm -rf "$DEST"
mv "$DEST.part" "$DEST"
LD_LIBRARY_PATH="$PWD/$DEST/usr/lib/x86_64-linux-gnu:$PWD/$DEST/usr/lib" "$DEST/usr/bin/ogrinfo" --version
