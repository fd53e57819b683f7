// A KTBT_ timer whose `ticks` cannot be read (a blackboard entry not set yet) starts no
// activation: once the entry is set, the next tick reads the count afresh (ktbt_btcpp.hpp).
// Prints, for KTBT_TT1 then KTBT_TT2: "error" or "no error" for the first tick, then the
// status of three ticks after the entry is set to 2.
#include <iostream>

#include "behaviortree_cpp/bt_factory.h"
#include "ktbt_btcpp.hpp"

int main()
{
  BT::BehaviorTreeFactory factory;
  ktbt::registerNodes(factory);
  for(const std::string id : { "KTBT_TT1", "KTBT_TT2" })
  {
    auto tree = factory.createTreeFromText(
        "<root BTCPP_format=\"4\"><BehaviorTree ID=\"Main\"><" + id +
        " ticks=\"{n}\"><AlwaysSuccess/></" + id + "></BehaviorTree></root>");
    try
    {
      tree.tickExactlyOnce();
      std::cout << id << " no error\n";
    }
    catch(const std::exception&)
    {
      std::cout << id << " error\n";
    }
    tree.rootBlackboard()->set<unsigned>("n", 2);
    for(int tick = 0; tick < 3; ++tick)
    {
      std::cout << id << " " << BT::toStr(tree.tickExactlyOnce()) << "\n";
    }
  }
  return 0;
}
