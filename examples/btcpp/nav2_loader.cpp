// Nav2's way of loading a behavior tree by ID, on its own: what a NavigateToPose goal naming a
// tree ID makes Nav2's bt_navigator do with its bt_search_directories (spec/stringbt.md,
// section 12.2), so that the files a KT-BT agent exports beside Nav2's own can be checked
// against BehaviorTree.CPP without ROS.
//
//   ktbt peer run --vocabulary nav.toml --export-learned trees/ --tree-id 'OpenLeftDoor=...' ...
//   nav2_loader model.xml OpenLeftDoor trees/ [MORE_DIRS...] [--true CALL]...
//
// It follows nav2_behavior_tree's BtActionServer::loadBehaviorTree for a goal that names an ID
// (not a file ending in .xml) and BehaviorTreeEngine::parseTreeInfo, as of navigation2's main
// branch in 2026: for each directory in turn, for each directory entry whose extension is
// ".xml", read the IDs of its <BehaviorTree> elements with tinyxml2 (a file that does not parse
// or has no ID is skipped; several trees without main_tree_to_execute is an error); a file with
// an ID already registered is skipped and listed at the end; every other file is registered
// with registerBehaviorTreeFromFile. Then createTree(ID) on a fresh blackboard. Any exception
// while registering or creating fails the whole load, as it fails the goal in Nav2
// (FAILED_TO_LOAD_BEHAVIOR_TREE). The tree is then ticked until it is no longer RUNNING, as
// BehaviorTreeEngine::run does (without its loop rate), at most --ticks N times (default 1000).
//
// Nav2's nodes come from its plugin libraries; here every condition and action that the
// <TreeNodesModel> of MODEL.xml declares is registered as a scripted leaf (scripted.hpp). It
// prints "registered FILE", "skipped FILE: WHY", "conflicting FILE...", "created ID", each
// call of an action, and "result SUCCESS|FAILURE"; a load that fails prints "error WHY" and
// exits 1. A usage mistake exits 2.
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "behaviortree_cpp/bt_factory.h"
#include "scripted.hpp"
#include "tinyxml2/tinyxml2.h"

namespace fs = std::filesystem;
using ktbt_scripted::say;

namespace
{

/// What BehaviorTreeEngine::parseTreeInfo returns.
struct BTInfo
{
  std::vector<std::string> behavior_tree_ids;
  std::string main_id;
};

BTInfo parseTreeInfo(const std::string& filename)
{
  BTInfo info;
  tinyxml2::XMLDocument doc;
  if(doc.LoadFile(filename.c_str()) != tinyxml2::XML_SUCCESS)
  {
    say("could not parse " + filename);
    return info;
  }
  tinyxml2::XMLElement* root = doc.RootElement();
  if(!root)
  {
    say("no root element in " + filename);
    return info;
  }
  for(auto* bt = root->FirstChildElement("BehaviorTree"); bt;
      bt = bt->NextSiblingElement("BehaviorTree"))
  {
    const char* id = bt->Attribute("ID");
    if(id)
    {
      info.behavior_tree_ids.emplace_back(id);
    }
  }
  const char* main_attr = root->Attribute("main_tree_to_execute");
  if(main_attr)
  {
    info.main_id = main_attr;
  }
  if(info.main_id.empty())
  {
    if(info.behavior_tree_ids.size() == 1)
    {
      info.main_id = info.behavior_tree_ids[0];
    }
    else if(info.behavior_tree_ids.size() > 1)
    {
      throw std::runtime_error("Multiple BehaviorTree elements found in " + filename +
                               " but no main_tree_to_execute attribute specified. Unable to "
                               "determine main tree.");
    }
  }
  return info;
}

/// Every .xml file of the directories, as BtActionServer::loadBehaviorTree registers them
/// for a goal that names a tree ID.
void registerAll(BT::BehaviorTreeFactory& factory, const std::vector<std::string>& directories)
{
  std::set<std::string> registered_ids;
  std::vector<std::string> conflicting_files;
  for(const auto& directory : directories)
  {
    for(const auto& entry : fs::directory_iterator(directory))
    {
      if(entry.path().extension() != ".xml")
      {
        continue;
      }
      auto tree_info = parseTreeInfo(entry.path().string());
      if(tree_info.behavior_tree_ids.empty())
      {
        say("skipped " + entry.path().string() + ": missing ID");
        continue;
      }
      bool conflict_found = false;
      for(const auto& id : tree_info.behavior_tree_ids)
      {
        if(registered_ids.count(id))
        {
          conflict_found = true;
          break;
        }
      }
      if(conflict_found)
      {
        conflicting_files.push_back(entry.path().string());
        continue;
      }
      factory.registerBehaviorTreeFromFile(entry.path().string());
      say("registered " + entry.path().filename().string());
      for(const auto& id : tree_info.behavior_tree_ids)
      {
        registered_ids.insert(id);
      }
    }
  }
  if(!conflicting_files.empty())
  {
    std::string files_list;
    for(const auto& file : conflicting_files)
    {
      files_list += (files_list.empty() ? "" : ", ") + file;
    }
    say("conflicting files not loaded: " + files_list);
  }
}

std::string readFile(const fs::path& path)
{
  std::ifstream in(path, std::ios::binary);
  if(!in)
  {
    throw std::runtime_error("cannot read " + path.string());
  }
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

}  // namespace

int main(int argc, char** argv)
{
  const char* usage = "usage: nav2_loader MODEL.xml TREE_ID DIR [DIR...] [--true CALL]... "
                      "[--ticks N]\n";
  std::vector<std::string> positional;
  std::set<std::string> holding;  // the --true calls: the scripted conditions that hold
  long ticks = 1000;
  for(int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if(arg == "--true" || arg == "--ticks")
    {
      if(i + 1 == argc)
      {
        std::cerr << "error: " << arg << ": needs a value\n" << usage;
        return 2;
      }
      const std::string value = argv[++i];
      if(arg == "--true")
      {
        holding.insert(value);
        continue;
      }
      try
      {
        std::size_t read = 0;
        ticks = std::stol(value, &read);
        if(read != value.size() || ticks < 1)
          throw std::invalid_argument(value);
      }
      catch(const std::exception&)
      {
        std::cerr << "error: --ticks: not a positive whole number: " << value << "\n";
        return 2;
      }
      continue;
    }
    positional.push_back(arg);
  }
  if(positional.size() < 3)
  {
    std::cerr << usage;
    return 2;
  }
  const std::string tree_id = positional[1];
  const std::vector<std::string> directories(positional.begin() + 2, positional.end());
  BT::BehaviorTreeFactory factory;
  try
  {
    ktbt_scripted::registerScripted(factory, ktbt_scripted::readModel(readFile(positional[0])),
                                    holding);
  }
  catch(const std::exception& err)
  {
    std::cerr << "error: MODEL.xml: " << err.what() << "\n";
    return 2;
  }
  try
  {
    registerAll(factory, directories);
  }
  catch(const std::exception& err)
  {
    say(std::string("error Exception registering behavior trees: ") + err.what());
    return 1;
  }
  BT::Tree tree;
  try
  {
    tree = factory.createTree(tree_id, BT::Blackboard::create());
    say("created " + tree_id);
  }
  catch(const std::exception& err)
  {
    say(std::string("error Exception when creating BT tree from ID: ") + err.what());
    return 1;
  }
  BT::NodeStatus result = BT::NodeStatus::RUNNING;
  try
  {
    for(long tick = 0; tick < ticks && result == BT::NodeStatus::RUNNING; ++tick)
    {
      result = tree.tickOnce();
      if(result == BT::NodeStatus::RUNNING)
      {
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      }
    }
  }
  catch(const std::exception& err)
  {
    say(std::string("error Behavior tree threw exception: ") + err.what());
    return 1;
  }
  say(std::string("result ") + BT::toStr(result));
  tree.haltTree();
  return 0;
}
