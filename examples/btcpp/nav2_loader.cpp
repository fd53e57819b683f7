// Nav2's two ways of loading a behavior tree, on their own, so that what a KT-BT agent exports
// can be checked against BehaviorTree.CPP without ROS (spec/stringbt.md, sections 12.2 and
// 12.3):
//
//   nav2_loader MODEL.xml TREE_ID DIR [MORE_DIRS...]  [OPTIONS]   newer Nav2: by ID
//   nav2_loader MODEL.xml --jazzy FILE.xml              [OPTIONS]   Nav2 on Jazzy: a file path
//
//   OPTIONS: --plugin NAME (repeated), --goal TEXT, --true CALL (repeated), --ticks N
//
// Both follow navigation2's source, read at its branches:
//
// * Plugins, first (both): BehaviorTreeEngine's constructor (nav2_behavior_tree/src/
//   behavior_tree_engine.cpp) registers every library of bt_navigator's plugin_lib_names with
//   factory.registerFromPlugin(BT::SharedLibrary::getOSName(NAME)): the library
//   lib<NAME>.so, found by the dynamic loader (LD_LIBRARY_PATH, as for Nav2's own plugins),
//   whose BT_REGISTER_NODES function registers its nodes. A library that does not load is an
//   error (Nav2's bt_navigator fails to configure). On Jazzy the constructor then disables
//   the exception BT.CPP's ReactiveSequence and ReactiveFallback throw for two asynchronous
//   children (EnableException(false)), as done here with --jazzy.
//
// * --jazzy: the jazzy branch's BtActionServer::loadBehaviorTree (nav2_behavior_tree/include/
//   nav2_behavior_tree/bt_action_server_impl.hpp), which bt_navigator calls with the
//   default_nav_to_pose_bt_xml parameter at activation and with a NavigateToPose goal's
//   behavior_tree field (NavigateToPoseNavigator::goalReceived, nav2_bt_navigator/src/
//   navigators/navigate_to_pose.cpp): the field is a file path, never an ID (Jazzy, like
//   Kilted, has no bt_search_directories). The file must open (std::ifstream::good), then
//   createTreeFromFile(FILE, blackboard) builds its main_tree_to_execute: BT.CPP reads each
//   <include path="..."> of it relative to the including file's folder, so a learned item at
//   a stable path (<ID>.xml) is a <SubTree ID="..."> of the robot's navigation tree.
//
// * By ID: navigation2's main branch (since its PR #5426, August 2025; also its lyrical
//   branch), BtActionServer::loadBehaviorTree for a goal naming an ID (not a name ending in
//   .xml) with BehaviorTreeEngine::parseTreeInfo: for each directory in turn, for each entry
//   whose extension is ".xml", read the IDs of its <BehaviorTree> elements with tinyxml2 (a
//   file that does not parse or has no ID is skipped; several trees without
//   main_tree_to_execute is an error); a file with an ID already registered is skipped and
//   listed at the end; every other file is registered with registerBehaviorTreeFromFile. Then
//   createTree(ID). A TREE_ID ending in .xml is a file, registered first (its
//   main_tree_to_execute is the tree), then every other file of the directories, as there.
//
// Either way, any exception while loading fails the whole load, as it fails the goal in Nav2
// (FAILED_TO_LOAD_BEHAVIOR_TREE). As loadBehaviorTree does, every subtree's blackboard then
// gets Nav2's timeouts (server_timeout, cancel_timeout, bt_loop_duration,
// wait_for_service_timeout; not its ROS node); NavigateToPoseNavigator::initializeGoalPose
// then puts the goal on the blackboard as "goal" (goal_blackboard_id), here the --goal TEXT as
// a string. The tree is then ticked until it is no longer RUNNING, as BehaviorTreeEngine::run
// does (without its loop rate), at most --ticks N times (default 1000).
//
// Nav2's own nodes come from its plugin libraries; here every condition and action that the
// <TreeNodesModel> of MODEL.xml declares, unless a plugin registered it, is registered as a
// scripted leaf (scripted.hpp) standing in for it. It prints "registered FILE",
// "skipped FILE: WHY", "conflicting FILE...", "created ID", each call of an action, and
// "result SUCCESS|FAILURE"; a load that fails prints "error WHY" and exits 1. A usage mistake
// exits 2.
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
#include "behaviortree_cpp/controls/reactive_fallback.h"
#include "behaviortree_cpp/controls/reactive_sequence.h"
#include "behaviortree_cpp/utils/shared_library.h"
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

/// Every .xml file of the directories but `skip_file`, as BtActionServer::loadBehaviorTree's
/// register_all_bt_files registers them; `registered_ids` holds the IDs registered before.
void registerAll(BT::BehaviorTreeFactory& factory, const std::vector<std::string>& directories,
                 std::set<std::string>& registered_ids, const std::string& skip_file = "")
{
  std::vector<std::string> conflicting_files;
  for(const auto& directory : directories)
  {
    for(const auto& entry : fs::directory_iterator(directory))
    {
      if(entry.path().extension() != ".xml")
      {
        continue;
      }
      if(!skip_file.empty() && entry.path().string() == skip_file)
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

/// The newer Nav2's loadBehaviorTree: the tree `file_or_id` names, from the directories.
BT::Tree loadById(BT::BehaviorTreeFactory& factory, const std::string& file_or_id,
                  const std::vector<std::string>& directories, BT::Blackboard::Ptr blackboard)
{
  std::set<std::string> registered_ids;
  std::string main_id;
  const bool is_bt_id = !(file_or_id.size() >= 4 &&
                          file_or_id.compare(file_or_id.size() - 4, 4, ".xml") == 0);
  try
  {
    if(!is_bt_id)
    {
      auto tree_info = parseTreeInfo(file_or_id);
      if(tree_info.main_id.empty())
      {
        throw std::runtime_error("Failed to extract ID from " + file_or_id);
      }
      main_id = tree_info.main_id;
      factory.registerBehaviorTreeFromFile(file_or_id);
      say("registered " + fs::path(file_or_id).filename().string());
      registered_ids.insert(tree_info.behavior_tree_ids.begin(),
                            tree_info.behavior_tree_ids.end());
      registerAll(factory, directories, registered_ids, file_or_id);
    }
    else
    {
      main_id = file_or_id;
      registerAll(factory, directories, registered_ids);
    }
  }
  catch(const std::exception& err)
  {
    throw std::runtime_error(std::string("Exception registering behavior trees: ") + err.what());
  }
  try
  {
    BT::Tree tree = factory.createTree(main_id, blackboard);
    say("created " + main_id);
    return tree;
  }
  catch(const std::exception& err)
  {
    throw std::runtime_error(std::string("Exception when creating BT tree from ID: ") +
                             err.what());
  }
}

/// Jazzy's loadBehaviorTree: the tree of the file at `filename`, its <include>s with it.
BT::Tree loadJazzy(BT::BehaviorTreeFactory& factory, const std::string& filename,
                   BT::Blackboard::Ptr blackboard)
{
  std::ifstream xml_file(filename);
  if(!xml_file.good())
  {
    throw std::runtime_error("Couldn't open input XML file: " + filename);
  }
  try
  {
    BT::Tree tree = factory.createTreeFromFile(filename, blackboard);
    say("created " + filename);
    return tree;
  }
  catch(const std::exception& err)
  {
    throw std::runtime_error(std::string("Exception when loading BT: ") + err.what());
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
  const char* usage = "usage: nav2_loader MODEL.xml TREE_ID DIR [DIR...] [OPTIONS]\n"
                      "       nav2_loader MODEL.xml --jazzy FILE.xml [OPTIONS]\n"
                      "OPTIONS: --plugin NAME... --goal TEXT --true CALL... --ticks N\n";
  std::vector<std::string> positional, plugins;
  std::set<std::string> holding;  // the --true calls: the scripted conditions that hold
  std::string goal;
  bool jazzy = false, has_goal = false;
  long ticks = 1000;
  for(int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if(arg == "--jazzy")
    {
      jazzy = true;
      continue;
    }
    if(arg == "--true" || arg == "--ticks" || arg == "--plugin" || arg == "--goal")
    {
      if(i + 1 == argc)
      {
        std::cerr << "error: " << arg << ": needs a value\n" << usage;
        return 2;
      }
      const std::string value = argv[++i];
      if(arg == "--true")
        holding.insert(value);
      else if(arg == "--plugin")
        plugins.push_back(value);
      else if(arg == "--goal")
      {
        goal = value;
        has_goal = true;
      }
      else
      {
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
      }
      continue;
    }
    positional.push_back(arg);
  }
  if(jazzy ? positional.size() != 2 : positional.size() < 3)
  {
    std::cerr << usage;
    return 2;
  }
  BT::BehaviorTreeFactory factory;
  try
  {
    BT::SharedLibrary loader;
    for(const auto& name : plugins)
    {
      factory.registerFromPlugin(loader.getOSName(name));
      say("plugin " + name);
    }
  }
  catch(const std::exception& err)
  {
    say(std::string("error plugin_lib_names: ") + err.what());
    return 1;
  }
  if(jazzy)
  {
    BT::ReactiveSequence::EnableException(false);
    BT::ReactiveFallback::EnableException(false);
  }
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
  auto blackboard = BT::Blackboard::create();
  BT::Tree tree;
  try
  {
    if(jazzy)
    {
      tree = loadJazzy(factory, positional[1], blackboard);
    }
    else
    {
      const std::vector<std::string> directories(positional.begin() + 2, positional.end());
      tree = loadById(factory, positional[1], directories, blackboard);
    }
  }
  catch(const std::exception& err)
  {
    say(std::string("error ") + err.what());
    return 1;
  }
  using std::chrono::milliseconds;
  for(auto& subtree : tree.subtrees)
  {
    subtree->blackboard->set<milliseconds>("server_timeout", milliseconds(20));
    subtree->blackboard->set<milliseconds>("cancel_timeout", milliseconds(20));
    subtree->blackboard->set<milliseconds>("bt_loop_duration", milliseconds(10));
    subtree->blackboard->set<milliseconds>("wait_for_service_timeout", milliseconds(1000));
  }
  if(has_goal)
  {
    blackboard->set<std::string>("goal", goal);
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
