// Re-save every grid of an OpenVDB file with a chosen compression (used by make_fixtures.py;
// pyopenvdb always writes OpenVDB's default, blosc + active mask).
//   recompress none|mask|zip|blosc IN.vdb OUT.vdb
// none: raw values; mask: active-mask compression only (raw values, inactive ones dropped
// where the mask allows); zip, blosc: active-mask compression plus that codec.
#include <openvdb/openvdb.h>
#include <cstring>
#include <iostream>

int main(int argc, char** argv)
{
    if (argc != 4) {
        std::cerr << "usage: recompress none|mask|zip|blosc IN OUT\n";
        return 2;
    }
    openvdb::initialize();
    uint32_t flags;
    const std::string mode = argv[1];
    if (mode == "none") flags = openvdb::io::COMPRESS_NONE;
    else if (mode == "mask") flags = openvdb::io::COMPRESS_ACTIVE_MASK;
    else if (mode == "zip") flags = openvdb::io::COMPRESS_ACTIVE_MASK | openvdb::io::COMPRESS_ZIP;
    else if (mode == "blosc") flags = openvdb::io::COMPRESS_ACTIVE_MASK | openvdb::io::COMPRESS_BLOSC;
    else {
        std::cerr << "unknown compression " << mode << "\n";
        return 2;
    }
    openvdb::io::File in(argv[2]);
    in.open();
    openvdb::GridPtrVecPtr grids = in.getGrids();
    in.close();
    openvdb::io::File out(argv[3]);
    out.setCompression(flags);
    out.write(*grids);
    out.close();
    return 0;
}
