// KT-BT's three BehaviorTree.CPP nodes as a plugin library, so that a program that loads its
// nodes by library name, as Nav2's bt_navigator loads every library of its plugin_lib_names
// (factory.registerFromPlugin(BT::SharedLibrary::getOSName("ktbt_nodes")), which is
// libktbt_nodes.so on Linux), runs the learned trees that use them (spec/stringbt.md, section
// 12.2): KTBT_TT1, KTBT_TT2 and KTBT_WaitTicks, the nodes of ktbt_btcpp/ktbt_btcpp.hpp that
// stringBT's tick timers are written as.
//
//   g++ -std=c++17 -shared -fPIC -DBT_PLUGIN_EXPORT -I ktbt_btcpp -I $BTCPP/include \
//       examples/btcpp/ktbt_nodes.cpp -L $BTCPP/lib -lbehaviortree_cpp -o libktbt_nodes.so
//
// BT_PLUGIN_EXPORT makes BT_REGISTER_NODES an exported C function (without it the macro
// declares a static one, for a program that links the nodes in). In a ROS 2 package, the same
// file is an add_library(ktbt_nodes SHARED ...) with
// target_compile_definitions(ktbt_nodes PRIVATE BT_PLUGIN_EXPORT), and bt_navigator's
// parameters name it: plugin_lib_names: ["ktbt_nodes"].
#include "behaviortree_cpp/bt_factory.h"
#include "ktbt_btcpp.hpp"

BT_REGISTER_NODES(factory)
{
  ktbt::registerNodes(factory);
}
